# eqhrl_ros workspace: one entry point for setup, tests and the demo.
#
#   make demo   set everything up, then train EQSAC on Pendulum-v1 through the ROS nodes
#   make test   set everything up, then run the test suite
#
# Setup is stamp-based: a second run redoes only what changed.

SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c

PYTHON ?= python3.11
VENV := .venv
VPY := $(VENV)/bin/python
BUILD := build
# The PyPI ROS wheels are a ROS prefix of their own: share/ament_index, lib/, include/.
ROS_ENV := AMENT_PREFIX_PATH=$(CURDIR)/$(VENV) CMAKE_PREFIX_PATH=$(CURDIR)/$(VENV)
CMAKE_VENV_ARGS := -DPython3_EXECUTABLE=$(CURDIR)/$(VPY) \
	-DCMAKE_PROJECT_INCLUDE=$(CURDIR)/tools/cmake/venv_underlay_fixes.cmake \
	-DBUILD_TESTING=OFF
# pip on some machines lists index folders that do not exist; keep its output readable.
PIP_QUIET := { grep -v "is ignored: it is neither a file nor a directory" || true; }

INTERFACE_SRC := $(shell find eqhrl_interfaces -type f 2>/dev/null)
# Everything that goes into the installed eqhrl_ros (tests run from the source tree).
PACKAGE_SRC := $(shell find eqhrl_ros -type f -not -path '*/tests/*' -not -path 'eqhrl_ros/build/*' \
	-not -path '*.egg-info/*' -not -path '*/__pycache__/*' 2>/dev/null)

.PHONY: system-deps setup ros2-tools lint test test-fast test-noble demo bench bench-seeds bench-pixels bench-learner bench-ros bench-flood bench-actors bench-multi-host bench-busy profile clean lock

setup: $(VENV)/.stamp-eqhrl_ros

# What the tests drive besides Python: tmux (keyboard_teleop in a real terminal) and Debian's
# chromium and chromium-driver (advice_console in a real browser). apt, as root; only what is missing.
SYSTEM_TOOLS := tmux:tmux chromium:chromium chromedriver:chromium-driver
system-deps:
	@missing=""; for pair in $(SYSTEM_TOOLS); do \
	  command -v $${pair%%:*} >/dev/null || missing="$$missing $${pair#*:}"; done; \
	if [ -n "$$missing" ]; then \
	  command -v apt-get >/dev/null || { echo "error: the tests drive$$missing: install them (no apt-get here)"; exit 1; }; \
	  [ "$$(id -u)" = 0 ] || { echo "error: the tests drive$$missing: run 'sudo apt-get install$$missing' (or make test as root)"; exit 1; }; \
	  echo "installing$$missing (apt)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	fi

$(VENV)/.stamp-deps: requirements.txt constraints.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; the ROS 2 wheels need CPython 3.11 (set PYTHON=...)"; exit 1; }
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install -q -r requirements.txt -c constraints.txt 2>&1 | $(PIP_QUIET)
	touch $@

$(VENV)/.stamp-interfaces: $(VENV)/.stamp-deps $(INTERFACE_SRC) tools/cmake/venv_underlay_fixes.cmake
	rm -rf $(BUILD)/eqhrl_interfaces && mkdir -p $(BUILD)
	$(ROS_ENV) $(VENV)/bin/cmake -S eqhrl_interfaces -B $(BUILD)/eqhrl_interfaces \
		-DCMAKE_INSTALL_PREFIX=$(CURDIR)/$(VENV) $(CMAKE_VENV_ARGS) >$(BUILD)/interfaces-configure.log \
		|| { cat $(BUILD)/interfaces-configure.log; exit 1; }
	$(ROS_ENV) $(VENV)/bin/cmake --build $(BUILD)/eqhrl_interfaces --target install -j2 >$(BUILD)/interfaces-build.log \
		|| { tail -50 $(BUILD)/interfaces-build.log; exit 1; }
	touch $@

# A regular (not editable) install: it puts the ament index entry, params and launch
# files into .venv/share like a ROS install space, which editable installs skip.
$(VENV)/.stamp-eqhrl_ros: $(VENV)/.stamp-interfaces $(PACKAGE_SRC)
	$(VPY) -m pip install -q --no-deps --no-build-isolation --force-reinstall ./eqhrl_ros 2>&1 | $(PIP_QUIET)
	rm -rf eqhrl_ros/build eqhrl_ros/*.egg-info
	touch $@

# The real `ros2` CLI and `ros2 launch` (not on PyPI) for the tests that run them, where the
# project's machines have their sources (../shared/ros2-tools); a user's clone goes without
# them, and those tests say so in one line.
ROS2_TOOLS_INSTALL := $(wildcard ../shared/ros2-tools/install.sh)
ros2-tools: $(if $(ROS2_TOOLS_INSTALL),$(VENV)/.stamp-ros2-tools)
	@[ -n "$(ROS2_TOOLS_INSTALL)" ] || echo "no ../shared/ros2-tools: the tests of the real ros2 CLI and ros2 launch are skipped"

$(VENV)/.stamp-ros2-tools: $(VENV)/.stamp-deps $(ROS2_TOOLS_INSTALL)
	bash $(ROS2_TOOLS_INSTALL) $(VENV) . .ros2-tools 2>&1 | $(PIP_QUIET)
	touch $@

# ruff: lint and format check of the whole tree (rules in ruff.toml); mypy: types of the core (mypy.ini).
lint: $(VENV)/.stamp-deps
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

# Two pytest-xdist workers: the tests mostly wait on processes and ROS, so two share two cores
# well. Each worker has a ROS domain of its own and they share one colcon build (tests/conftest.py);
# TEST_WORKERS=0 runs the tests in one process.
TEST_WORKERS ?= 2
PYTEST_WORKERS := -n $(TEST_WORKERS)

test: system-deps setup ros2-tools lint
	$(VENV)/bin/pytest eqhrl_ros/tests $(PYTEST_WORKERS) --durations=25

# The suite with what rosdep installs on Ubuntu 24.04 (tools/noble-versions.txt: numpy 1.26,
# scipy 1.11, aiohttp 3.9, ...) before the venv's newer pins, as a ROS install runs the nodes.
# Not part of make test.
NOBLE := $(BUILD)/noble
test-noble: setup ros2-tools
	rm -rf $(NOBLE)
	$(VPY) -m pip install -q --no-deps --target $(NOBLE) -r tools/noble-versions.txt 2>&1 | $(PIP_QUIET)
	PYTHONPATH=$(CURDIR)/$(NOBLE) $(VENV)/bin/pytest eqhrl_ros/tests $(PYTEST_WORKERS) --durations=10

# A developer's loop: everything but the tests marked slow, stopping at the first failure.
test-fast: setup
	$(VENV)/bin/pytest eqhrl_ros/tests $(PYTEST_WORKERS) -m "not slow" -x -q

demo: setup
	$(VENV)/bin/eqhrl-demo

# Benchmarks (not part of the tests): Stable-Baselines3 and SBX are benchmark-only dependencies.
$(VENV)/.stamp-bench: $(VENV)/.stamp-eqhrl_ros benchmarks/requirements.txt
	$(VPY) -m pip install -q -r benchmarks/requirements.txt -c constraints.txt 2>&1 | $(PIP_QUIET)
	touch $@

# Each exits non-zero when a speed target is missed (bench_learner: against SBX); `bench` runs both.
# bench_ros's targets are for the EventsExecutor (opt-in; see flood.py).
bench: $(VENV)/.stamp-bench
	$(VPY) benchmarks/bench_learner.py; learner=$$?; $(VPY) benchmarks/bench_ros.py --executor events; ros=$$?; \
	  exit $$(( learner || ros ))

bench-learner: $(VENV)/.stamp-bench
	$(VPY) benchmarks/bench_learner.py

bench-ros: $(VENV)/.stamp-eqhrl_ros
	$(VPY) benchmarks/bench_ros.py --executor events

# A hostile flood on the learner's and the env's input topics (memory and recovery), and on the
# trainer's /transitions from a name it does not hear (memory during and after).
bench-flood: $(VENV)/.stamp-eqhrl_ros
	$(VPY) benchmarks/flood.py --target learner; learner=$$?; $(VPY) benchmarks/flood.py --target env; env=$$?; \
	  $(VPY) benchmarks/flood_trainer.py; trainer=$$?; exit $$(( learner || env || trainer ))

# What torch.compile and bfloat16 matrix products would buy the update (evidence, no target).
# Actors and a trainer against the lock-step learner; exits 1 if a 50 Hz env had
# late steps with the actor.
bench-actors: $(VENV)/.stamp-eqhrl_ros
	$(VPY) benchmarks/bench_actors.py

# Actors and a trainer on hosts in network namespaces, with packet loss (nftables), and the fault
# run (a 30 s cut and a trainer restart). As root; installs nftables with apt where it is missing.
bench-multi-host: $(VENV)/.stamp-eqhrl_ros
	@command -v nft >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nftables >/dev/null; } || \
	  { echo "error: bench-multi-host needs nftables (apt-get install nftables) and root"; exit 1; }
	$(VPY) benchmarks/bench_multi_host.py
	$(VPY) benchmarks/bench_multi_host.py --cut --variants default

# A busy machine: exits 1 if our default keeps under 40 % of its quiet
# speed beside one CPU-bound process, in-process and through ROS.
bench-busy: $(VENV)/.stamp-eqhrl_ros
	a=0; b=0; $(VPY) benchmarks/bench_busy.py --hidden 256 --batch 256 || a=$$?; \
	$(VPY) benchmarks/bench_busy.py --rounds 2 --ros-episodes 8 --settings "2:default:fitted" "2:spin 1000" || b=$$?; \
	exit $$(( a || b ))

# Seeds together against seeds apart: the curve for N seeds, and a
# non-zero exit if 10 seeds together miss 2x (Pendulum) or 1.5x (LunarLander) seeds apart.
bench-seeds: $(VENV)/.stamp-eqhrl_ros
	$(VPY) benchmarks/bench_seeds.py

# Learning from pixels at 84x84: our camera learner beside a plain DrQ-v2-style loop (no target).
bench-pixels: $(VENV)/.stamp-eqhrl_ros
	$(VPY) benchmarks/bench_pixels.py

# Where a training step's time goes (torch.profiler's top operators), and inside the compiled
# update: products, fused kernels and the rest of the call; each thread of the loop, its
# sleeps and, with linux perf, where its time goes (docs/performance.md, issue 48).
profile: $(VENV)/.stamp-eqhrl_ros
	$(VPY) benchmarks/profile_learner.py --mode sac
	$(VPY) benchmarks/profile_learner.py --mode eqsac
	$(VPY) benchmarks/profile_update.py
	$(VPY) benchmarks/kernel_options.py
	$(VPY) benchmarks/profile_threads.py
	$(VPY) benchmarks/acting_ahead.py

# Refresh constraints.txt from the current .venv (after changing requirements.txt).
lock: $(VENV)/.stamp-deps
	{ echo "# Lock file: exact versions of every package in .venv (pip install -c constraints.txt)."; \
	  echo "# Regenerate with: make lock"; \
	  $(VPY) -m pip freeze --exclude-editable | sed -e 's/^torch==2.13.0+cpu/torch==2.13.0/'; } > constraints.txt

clean:
	rm -rf $(VENV) $(BUILD) .ros2-tools runs
