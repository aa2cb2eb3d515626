"""mkflight: onboard flight software for a laser-guided MikroKopter quadrotor."""

__version__ = "0.1.0"
