"""ROS-free core: usable in-process without rclpy (enforced by .importlinter and test/test_layout.py)."""
