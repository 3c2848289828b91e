"""Rollout workers beyond this process: the worker pool (shared memory), Ray actors, the weights and rollouts they
exchange, and the experience source over either."""
