"""Tests of mkflight.frames (rotations, level acceleration) and mkflight.estimation."""
