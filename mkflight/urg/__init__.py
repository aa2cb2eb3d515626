"""The Hokuyo URG-04LX: SCIP 2.0 codec, reply parser, units, laser-hat height and the driver.

``codec`` (sum, number encoding, command builders, status meanings), ``replies`` (typed
replies and the incremental parser), ``units`` (PP parameters, mm -> m, step -> angle,
timestamp wrap) are pure; only the driver awaits (``protocols/scip2.md``, SPEC §2).
"""
