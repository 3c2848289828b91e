"""The RoboCup SPL soccer scenario, ROS-free (field geometry today; world, rules and rewards next)."""
