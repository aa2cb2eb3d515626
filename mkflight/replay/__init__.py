"""``mkflight replay``: recorded flights back through mock serial ports (SPEC §6).

:mod:`~mkflight.replay.inputs` reads a flight folder, :mod:`~mkflight.replay.vloop` is the
lock-step clock, :mod:`~mkflight.replay.feeder` the mock devices,
:mod:`~mkflight.replay.daemon` the daemon as a replay runs it,
:mod:`~mkflight.replay.compare` the determinism check, :mod:`~mkflight.replay.report`
what a replay found, :mod:`~mkflight.replay.session` the folder and the loop run,
:mod:`~mkflight.replay.seed` and :mod:`~mkflight.replay.seed_run` the original system's
tables (TABLE III and IV of the 2011 QUT CyPhy MikroKopter documentation), and
:mod:`~mkflight.replay.run` puts a recorded flight's replay together.
"""
