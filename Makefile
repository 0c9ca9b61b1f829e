# polyc2bf_ros: two commands on a fresh machine, `make demo` and `make test`.
# Every target builds its own virtualenv (.venv) from requirements.lock (runtime pins;
# test, lint and bench add requirements-dev.lock) and installs this package into it; a
# second run reinstalls nothing unless a lock file or the package sources changed.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
DEPS_STAMP := $(VENV)/.deps-installed
DEV_STAMP := $(VENV)/.dev-deps-installed
PKG_STAMP := $(VENV)/.pkg-installed
# The filter's kernels are compiled ahead of time into polyc2bf_ros/core/kernels/_kernels*.so
# (polyc2bf_ros/core/kernels/jit.py): nodes then start in ~0.2 s without numba/LLVM in memory.
BUILD_KERNELS := PYTHONPATH=$(CURDIR) $(PY) -m polyc2bf_ros.core.kernels.build
PKG_SOURCES := setup.py setup.cfg package.xml \
	$(shell find polyc2bf_ros sim_bridge config launch resource bench/data -type f \
	        -not -name '*.pyc' -not -name '_kernels*' -not -name '_guards.py' -not -path '*/__pycache__/*' 2>/dev/null)

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

$(DEV_STAMP): requirements-dev.lock $(DEPS_STAMP)
	@echo "== installing the pinned development tools into $(VENV) (first run only)"
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.lock \
	  -r requirements-dev.lock
	@touch $@

$(PKG_STAMP): $(DEPS_STAMP) $(PKG_SOURCES)
	@echo "== compiling the filter's kernels ahead of time (numba pycc, about a minute)"
	@$(BUILD_KERNELS) || { rm -f polyc2bf_ros/core/kernels/_kernels*.so polyc2bf_ros/core/kernels/_kernels.digest \
	  polyc2bf_ros/core/kernels/_guards.py; \
	  echo "WARNING: the ahead-of-time kernel build failed (no C compiler or numba.pycc?);" \
	       "the filter compiles its kernels just in time instead (numba's cache, slower start)"; }
	@echo "== installing polyc2bf_ros into $(VENV)"
	@# setuptools copies into build/ and never deletes there: a module moved or removed since
	@# the last install would be installed again (and change the kernels' digest).
	rm -rf build
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation .
	@touch $@

test: $(PKG_STAMP) $(DEV_STAMP)
	$(PY) -m pytest -n $(PYTEST_WORKERS) $(PYTEST_ARGS) test

# `make test` (and anything run with CI set) uses hypothesis's fixed, derandomized profile:
# the same examples on every clone and run.  `make test-explore` (or HYPOTHESIS_PROFILE=explore
# on any pytest command) runs the property tests with 10x the examples on a fresh random seed;
# pin every counterexample it finds with @example next to its fix (test/conftest.py).
.PHONY: test-explore
test-explore: $(PKG_STAMP) $(DEV_STAMP)
	HYPOTHESIS_PROFILE=explore $(PY) -m pytest -n $(PYTEST_WORKERS) $(PYTEST_ARGS) \
	  test/core test/node/test_node_conversions.py test/sim/test_recorder.py

lint: $(PKG_STAMP) $(DEV_STAMP)
	$(PY) -m ruff check .

# Benchmarks print a table and write JSON under bench/results/ (bench/README.md; record keys:
# doc/design.md, result records).
bench: $(PKG_STAMP) $(DEV_STAMP)
	$(PY) bench/bench_core.py
	$(PY) bench/bench_clutter.py
	$(PY) bench/bench_node.py
	$(PY) bench/bench_node.py --obstacle-updates
	$(PY) bench/bench_obstacle_flood.py
	$(PY) bench/bench_logging.py
	$(PY) bench/bench_cold.py
	$(PY) bench/bench_sim.py
	$(PY) bench/bench_sim_closed_loop.py --floor  # merges its records into sim.json
	$(PY) bench/bench_prediction.py
	$(PY) bench/bench_scan_tracks.py

# The closed-loop demo: sim_bridge + nominal_controller + safety_filter as separate processes
# over localhost DDS, in lockstep; writes runs/<timestamp>/ (bag, metrics, trajectory plot).
demo: $(PKG_STAMP)
	$(PY) -m sim_bridge.demo --scenario $(SCENARIO) $(DEMO_ARGS)

# Every filter x scenario x seed, in-process lockstep; writes runs/eval/.
eval: $(PKG_STAMP)
	$(PY) -m sim_bridge.evaluation $(EVAL_ARGS)

clean:
	rm -rf $(VENV) build install log *.egg-info
