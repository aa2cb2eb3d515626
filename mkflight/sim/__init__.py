"""The simulator: a second opinion on the flight code, never a copy of it (SPEC §8).

* **The vehicle**: :mod:`~mkflight.sim.vehicle` (the rigid body flown by the FC's attitude
  loop, sub-stepped by :mod:`~mkflight.sim.vehicle_substep`), its landing gear, battery,
  gusts and sensors, and :mod:`~mkflight.sim.airframe` (the nominal airframe, or one drawn
  from the envelope).
* **The devices**, pure sans-I/O models served on pseudo-terminals
  (:mod:`~mkflight.sim.pty_server`): the FlightCtrl 0.84a (:mod:`~mkflight.sim.fc`) and the
  URG-04LX (:mod:`~mkflight.sim.urg`) ray-casting the room (:mod:`~mkflight.sim.room`).
* **The runs**: in real time for ``mkflight sim``, which ``fly --sim`` starts
  (:mod:`~mkflight.sim.live`, :mod:`~mkflight.sim.world`); in lock-step for ``sim hover``
  (:mod:`~mkflight.sim.hover`); over many random airframes, against an oracle flown on the
  truth, for ``sim envelope`` (:mod:`~mkflight.sim.envelope`, :mod:`~mkflight.sim.oracle`).

It reads only the ``sim`` config section: never the flight code's constants, calibration
or gains.
"""
