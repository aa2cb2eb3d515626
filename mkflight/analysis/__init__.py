"""The original system's analyses as pure functions, and the flight's own.

Accelerometer calibration (:mod:`~mkflight.analysis.calibrate`, §D) and flight time
(:mod:`~mkflight.analysis.flight_time`, §L) of the 2011 QUT CyPhy MikroKopter
documentation; the response lag (:mod:`~mkflight.analysis.latency`, §F), the attitude
response and the airframe identified from a flight (:mod:`~mkflight.analysis.attitude_fit`,
:mod:`~mkflight.analysis.identify`).
"""
