# polyc2bf_ros: two commands on a fresh machine, `make demo` and `make test`.
# Every target builds its own virtualenv (.venv) from requirements.lock (pinned)
# and installs this package into it; a second run reinstalls nothing unless the
# lock file or the package sources changed.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
DEPS_STAMP := $(VENV)/.deps-installed
PKG_STAMP := $(VENV)/.pkg-installed
# Nodes start in ~0.4 s from numba's cache instead of compiling for ~6 s (DDS tests rely on it).
COMPILE_KERNELS := from polyc2bf_ros.core.safety_filter import compile_kernels; compile_kernels()
PKG_SOURCES := setup.py setup.cfg package.xml \
	$(shell find polyc2bf_ros sim_bridge config launch resource -type f \
	        -not -name '*.pyc' -not -path '*/__pycache__/*' 2>/dev/null)

# DDS never leaves this machine. Tests pick a ROS_DOMAIN_ID per pytest worker
# (test/conftest.py).
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
PYTEST_WORKERS ?= 2
PYTEST_ARGS ?=
SCENARIO ?= long_wall
DEMO_ARGS ?=
EVAL_ARGS ?=

.PHONY: test demo eval bench lint venv clean

venv: $(PKG_STAMP)

$(PY):
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), \
	  "ROS 2 Jazzy wheels need Python 3.11; set PYTHON=/path/to/python3.11"'
	$(PYTHON) -m venv $(VENV)

$(DEPS_STAMP): requirements.lock | $(PY)
	@echo "== installing pinned dependencies into $(VENV) (first run only)"
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.lock
	@touch $@

$(PKG_STAMP): $(DEPS_STAMP) $(PKG_SOURCES)
	@echo "== installing polyc2bf_ros into $(VENV)"
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation .
	@echo "== compiling the filter's numba kernels into their on-disk caches (installed and source tree)"
	cd / && $(abspath $(PY)) -c "$(COMPILE_KERNELS)"
	PYTHONPATH=$(CURDIR) $(PY) -c "$(COMPILE_KERNELS)"
	@touch $@

test: $(PKG_STAMP)
	$(PY) -m pytest -n $(PYTEST_WORKERS) $(PYTEST_ARGS) test

lint: $(PKG_STAMP)
	$(PY) -m ruff check .

# Benchmarks print a table and write JSON under bench/results/ (DESIGN.md section 8).
bench: $(PKG_STAMP)
	$(PY) bench/bench_core.py
	$(PY) bench/bench_clutter.py
	$(PY) bench/bench_node.py
	$(PY) bench/bench_node.py --obstacle-updates
	$(PY) bench/bench_sim.py
	$(PY) bench/bench_sim_closed_loop.py --floor  # merges its records into sim.json

# The closed-loop demo: sim_bridge + nominal_controller + safety_filter as separate processes
# over localhost DDS, in lockstep; writes runs/<timestamp>/ (bag, metrics, trajectory plot).
demo: $(PKG_STAMP)
	$(PY) -m sim_bridge.demo --scenario $(SCENARIO) $(DEMO_ARGS)

# Every filter x scenario x seed, in-process lockstep; writes runs/eval/.
eval: $(PKG_STAMP)
	$(PY) -m sim_bridge.evaluate $(EVAL_ARGS)

clean:
	rm -rf $(VENV) build install log *.egg-info
