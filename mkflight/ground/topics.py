"""Topic and frame names shared by the live view and the MCAP export.

The original system's ROS topics keep their names and fields: ``/pose2D`` (TABLE V),
``/mikoImu`` (TABLE VI) and ``/mikoCmd`` (TABLE VII) of the 2011 QUT CyPhy MikroKopter
documentation. The rest are this project's, named after what they carry. One name per
thing, so that a Foxglove layout made on a live flight opens an exported one too.
"""

from typing import Final

# The original system's topics (TABLE V-VII).
POSE2D: Final = "/pose2D"
MIKO_IMU: Final = "/mikoImu"
MIKO_CMD: Final = "/mikoCmd"

# This project's topics.
SCAN: Final = "/scan"  #: the laser scan in the vehicle frame (foxglove.LaserScan)
POSE: Final = "/pose"  #: the estimated pose in the world frame (foxglove.PoseInFrame)
SETPOINT: Final = "/setpoint"  #: the held set-point in the world frame (foxglove.PoseInFrame)
TF: Final = "/tf"  #: world -> vehicle frame transform for the 3D panel
TF_STATIC: Final = "/tf_static"  #: map -> world, once (the export)
HEIGHT: Final = "/height"
ATTITUDE: Final = "/attitude"
VELOCITY: Final = "/velocity"  #: the velocity estimate
COMMAND: Final = "/command"  #: the ExternControl sent (MK counts) and its SI meaning
BATTERY: Final = "/battery"
PHASE: Final = "/phase"
FAILSAFE: Final = "/failsafe"
TRUTH: Final = "/truth"  #: the simulator's ground truth, when the folder has it

# Frames. "world" is W and "vehicle" is B of SPEC §1 (both z down, FRD); "map" is W
# turned z up (x forward, y left) for viewers that assume a z-up world.
WORLD_FRAME: Final = "world"
VEHICLE_FRAME: Final = "vehicle"
MAP_FRAME: Final = "map"  #: W turned z up: the 3D panel's display frame
