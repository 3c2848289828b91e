"""Adapters between the ROS-free core and ROS 2 messages. Everything here may import rclpy and dynenv_msgs."""
