"""ROS-free bag tooling built on rosbags: reading and writing rosbag2 bags of dynenv_msgs without rclpy."""
