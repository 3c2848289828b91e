"""ROS-free emulation of a robot's vision pipeline: what each robot's detector reports in one vision frame,
misses, confusions, false positives and position errors included (the paper §3.1; docs/perception.md)."""
