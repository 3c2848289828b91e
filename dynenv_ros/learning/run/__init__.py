"""A run's directory: checkpoints, the metrics log, the best policy, what the run cost, and the disk it needs."""
