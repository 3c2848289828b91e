# The two commands of the README are `make run` and `make test`; both bootstrap the clone first (idempotent).
SHELL := /bin/bash
VENV_PY := .venv/bin/python
HOST_PY := $(shell command -v python3.11 || command -v python3)
# Extra arguments: `make run ARGS="--set duration_s=30"`, `make test PYTEST_ARGS="-k interfaces"`.
ARGS ?=
PYTEST_ARGS ?=

.PHONY: run test test-fast lint bootstrap lock bench clean

bootstrap:
	@test -n "$(HOST_PY)" || { echo "error: Python 3.11 is required (python3.11 not found on PATH)"; exit 2; }
	@$(HOST_PY) tools/bootstrap.py

run: bootstrap
	@$(VENV_PY) -m dynenv_ros.main_job $(ARGS)

# ruff, mypy and import-linter (tools/lint.py); `make test` runs it first.
lint: bootstrap
	@$(VENV_PY) tools/lint.py

test: lint
	@$(VENV_PY) -m pytest -n 2 --durations=25 $(PYTEST_ARGS) test

# The quick, ROS-free subset while working (docs/setup.md#tests): no lint, no test marked `ros` or `slow`.
test-fast: bootstrap
	@$(VENV_PY) -m pytest -n 2 -m "not ros and not slow" $(PYTEST_ARGS) test

bench: bootstrap
	@$(VENV_PY) -m benchmarks $(ARGS)

lock:
	@$(HOST_PY) tools/lock.py

clean:
	rm -rf .venv build runs .pytest_cache .mypy_cache .ruff_cache .import_linter_cache
