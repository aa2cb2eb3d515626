"""The seed's analyses as pure functions: accelerometer calibration (§D), flight time (§L)."""
