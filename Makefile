# quadnav: the two commands of the quick start, and the pieces CI uses.
# torch is pinned to the CPU build CI has on disk; a plain `torch` may pull a multi-GB CUDA build.
VENV ?= .venv
PIP := $(VENV)/bin/pip
TORCH_PIN := torch==2.13.0
# The tests run in two passes: everything but the real-time flights on parallel workers, then the
# flights (the `e2e` marker: the daemon against the emulated vehicle side over MAVLink/UDP, with the
# flight's stale-input limits) one at a time, so a busy neighbour never starves a flight's sim.
PYTEST_ARGS ?= -n 3
E2E_PYTEST_ARGS ?=

.PHONY: dry-run test install install-dev lint system-deps

# The tests also drive Debian's headless Chromium (report screenshots) and systemd-analyze (unit
# checks). As root on Debian/Ubuntu they are installed when missing; otherwise we say what to install.
SYSTEM_DEPS := chromium:chromium systemd-analyze:systemd

$(VENV)/bin/python:
	python3 -m venv $(VENV)
	$(PIP) install -q --upgrade pip

# Both install the `mocap` extra (motioncapture): the dry run reads its emulated OptiTrack server through
# that library. It has x86-64 wheels; on ARM64 pip builds it from source (C++ toolchain, boost, eigen:
# docs/hardware.md, section 1). A vehicle that flies on PX4's own odometry needs only `pip install .`.
install: $(VENV)/bin/python
	$(PIP) install -q $(TORCH_PIN)
	$(PIP) install -q -e ".[mocap]"

install-dev: $(VENV)/bin/python
	$(PIP) install -q $(TORCH_PIN)
	$(PIP) install -q -e ".[dev,mocap]"

## Quick start 1: install, then fly Env 1 in the sim (its vehicle, camera and mocap as processes) with the bundled model.
dry-run: install
	$(VENV)/bin/quadnav-onboard --dry-run

system-deps:
	@missing=""; for pair in $(SYSTEM_DEPS); do cmd=$${pair%%:*}; pkg=$${pair##*:}; \
	  command -v $$cmd >/dev/null || missing="$$missing $$pkg"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing Debian packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else echo "missing system packages:$$missing (sudo apt-get install$$missing)"; exit 1; fi; fi

lint: install-dev
	$(VENV)/bin/ruff check .

## Quick start 2: install with the dev extra, then lint and run the whole test suite.
test: lint system-deps
	$(VENV)/bin/pytest $(PYTEST_ARGS) -m "not e2e"
	$(VENV)/bin/pytest $(E2E_PYTEST_ARGS) -m e2e
