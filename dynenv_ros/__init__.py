"""dynenv_ros: a ROS 2 emulation of a robot's vision pipeline with realistic perception failures, for MARL.

Subpackages: ``core`` (ROS-free simulation building blocks), ``bags`` (ROS-free bag tooling on rosbags),
``ros`` (conversions between the core and ROS messages), ``nodes`` (one ROS node per module),
``graph`` (running several nodes as processes: the main job).
"""

__version__ = "0.1.0"
