"""Experience collected in this process: the worlds a run learns in, the opponents, the rollout collector, and the
in-process experience source."""
