"""Running a graph of ROS 2 nodes as separate processes, without launch files (the main job, tests, benchmarks)."""
