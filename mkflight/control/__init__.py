"""Pure control laws (SPEC §4): PID, position/velocity, yaw, altitude, limits, phases.

Nothing here does I/O or reads a clock: values and ``dt_s`` in, values out. The flight
step (``mkflight.flight.step``) owns time, state and the failsafe.
"""
