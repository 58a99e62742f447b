# Build and test entry points for sins_align. Everything runs with the venv's python.
#   make setup   create .venv if missing, install pinned requirements and the package (-e)
#   make test    lint (ruff, zero findings) and run the test suite
#   make demo    run the demo
#   make bench   run every test/benchmarks/bench_*.py script (they print figures)
#   make clean   remove build/test by-products (never the venv)

SHELL := /bin/bash
.DEFAULT_GOAL := test

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
REQ    := .ci/requirements.txt
STAMP  := $(VENV)/.stamp
PIP_VERSION := 26.3

# Keep DDS traffic on this machine; tests also pick their own ROS_DOMAIN_ID (test/conftest.py).
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export PIP_DISABLE_PIP_VERSION_CHECK := 1
export PIP_NO_INPUT := 1

.PHONY: setup test demo bench clean

setup: $(STAMP)

$(PY):
	$(PYTHON) -m venv $(VENV)

# Re-runs only when the requirements or the build files change.
$(STAMP): $(REQ) setup.py setup.cfg | $(PY)
	$(PY) -m pip install -q pip==$(PIP_VERSION)
	$(PY) -m pip install -q -r $(REQ)
	$(PY) -m pip install -q --no-build-isolation --no-deps -e .
	touch $@

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q test

demo: $(STAMP)
	$(PY) -m sins_align.ros.demo

bench: $(STAMP)
	@set -e; shopt -s nullglob; scripts=(test/benchmarks/bench_*.py); \
	if [ $${#scripts[@]} -eq 0 ]; then echo "bench: no test/benchmarks/bench_*.py scripts yet"; fi; \
	for s in "$${scripts[@]}"; do echo "== $$s"; $(PY) "$$s"; done

clean:
	rm -rf build install log .pytest_cache sins_align.egg-info
	find sins_align test -name __pycache__ -type d -prune -exec rm -rf {} +
