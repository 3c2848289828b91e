"""Experiments made of many training runs: ``sweep`` (``dynenv-sweep``) trains a grid of runs as Ray tasks, locally
or on a cluster, evaluates each and merges the evaluations into results tables. It sits above ``learning`` (which
trains) and ``evaluation`` (which scores), and neither imports it."""
