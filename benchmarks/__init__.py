"""Benchmarks: `dynenv-bench <suite>` (or `make bench ARGS=<suite>`) prints figures; docs/benchmarks.md keeps them."""
