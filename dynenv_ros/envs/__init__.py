"""In-process environments over the ROS-free worlds: PettingZoo Parallel API and vectorised batches."""
