"""ROS-free core: usable in-process without rclpy (enforced by test/test_layout.py)."""
