"""Fixtures of the MK tests."""

from .fakes import pair

__all__ = ["pair"]
