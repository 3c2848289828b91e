"""ROS 2 nodes, one per module, each a thin adapter with ``main(args=None)`` for ``ros2 run dynenv_ros <node>``."""
