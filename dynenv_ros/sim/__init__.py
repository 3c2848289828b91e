"""ROS-free, scenario-independent simulation building blocks (clocks and rates today)."""
