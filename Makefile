# baxter_pnp: set-up, tests, demo and benchmarks. Everything installs itself on a fresh Debian 12
# (root): Debian's ROS 1 packages and Mesa's EGL (the fake's camera renderer) with apt, the pinned PyPI
# packages in .venv.
SHELL := /bin/bash
ROOT := $(abspath $(dir $(lastword $(MAKEFILE_LIST))))
VENV := $(ROOT)/.venv
PY := $(VENV)/bin/python
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

APT_PACKAGES := ros-core python3-rospy python3-rostest python3-rosunit python3-roslaunch \
	python3-rostopic python3-rosservice python3-rosnode python3-rosparam rosbash rospack-tools \
	python3-genpy python3-genmsg catkin python3-catkin-pkg cmake g++ make \
	python3-std-msgs ros-std-msgs python3-std-srvs ros-std-srvs python3-geometry-msgs ros-geometry-msgs \
	python3-sensor-msgs ros-sensor-msgs python3-rosgraph-msgs python3-tf2-msgs ros-tf2-msgs \
	python3-tf2-ros python3-yaml python3-venv python3-dev librostest-dev \
	python3-visualization-msgs ros-visualization-msgs python3-rosbag python3-roslz4 \
	libegl1 libegl-mesa0 libgl1-mesa-dri

STAMP_APT := $(ROOT)/.stamp-apt
STAMP_VENV := $(VENV)/.stamp-requirements
GENERATED := $(ROOT)/src/baxter_pnp/_generated/baxter_core_msgs/__init__.py
PTH := $(VENV)/lib/python3.11/site-packages/baxter_pnp.pth

.PHONY: all setup test demo demo-perception bench-perception bench-render bench-hand-eye bench-real-time rviz-screenshot clean

all: setup

setup: $(STAMP_APT) $(STAMP_VENV) $(GENERATED) $(PTH)

# Debian's ROS 1. Only touches apt when a package is missing, so a re-run costs one dpkg query.
$(STAMP_APT): Makefile
	@dpkg -s $(APT_PACKAGES) >/dev/null 2>&1 || { \
	  echo "make: installing Debian's ROS 1 packages"; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $(APT_PACKAGES) >/dev/null; }
	@touch $@

$(STAMP_VENV): requirements.txt $(STAMP_APT)
	@[ -x $(PY) ] || /usr/bin/python3 -m venv --system-site-packages $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.txt
	@touch $@

$(GENERATED): $(wildcard msg/*.msg srv/*.srv) tools/gen_msgs.py $(STAMP_APT)
	/usr/bin/python3 tools/gen_msgs.py $(ROOT)/src/baxter_pnp/_generated

# Makes `.venv/bin/python scripts/<name>.py` work from the repo root with no catkin workspace.
$(PTH): $(STAMP_VENV)
	@echo "$(ROOT)/src" > $@

# Two workers (one per core), a test file per worker at a time: each worker has its own rosmaster and fakes.
TEST_WORKERS ?= 2
test: setup
	cd $(ROOT) && $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile tests

# The whole system headless: rosmaster + fake Baxter + pick_square.py (pick, then place); outputs in out/demo.
demo: setup
	$(PY) scripts/demo.py --out out/demo

demo-perception: setup
	$(PY) scripts/perception_demo.py --out out/demo_perception

bench-perception: setup
	$(PY) scripts/bench_perception.py

# The fake's camera renderers side by side (ms per 640x400 frame, world-loop speed); README "Fake Baxter".
bench-render: setup
	$(PY) scripts/bench_render.py

# Hand-eye calibration on the fake vs its ground truth, and picks with / without it; README "Calibration on the robot".
bench-hand-eye: setup
	$(PY) scripts/bench_hand_eye.py

# The fake's real-time factor while the camera streams and a pick runs (paced); README "Fake Baxter".
bench-real-time: setup
	$(PY) scripts/bench_real_time.py

# rviz (config/baxter_pnp.rviz) on Xvfb after a table survey on the fake: docs/images/rviz.png. rviz and Xvfb are
# only needed here (and for `roslaunch ... rviz:=true`), so they are installed here, not by setup.
RVIZ_APT_PACKAGES := rviz xvfb xauth
rviz-screenshot: setup
	@dpkg -s $(RVIZ_APT_PACKAGES) >/dev/null 2>&1 || \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $(RVIZ_APT_PACKAGES) >/dev/null
	$(PY) scripts/rviz_screenshot.py

clean:
	rm -rf $(ROOT)/src/baxter_pnp/_generated out .pytest_cache
