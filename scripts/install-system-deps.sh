#!/usr/bin/env bash
# python3-venv: Debian's python3 installs packages only into a venv (PEP 668), and its venv module is a package
# of its own; the README's set-up makes one. Then the Debian packages the tests and benchmarks use: real ROS 1
# (ros_comm 1.15) as interop partner and golden reference, a C++ toolchain for the roscpp test node, iproute2
# for network-namespace tests, node and chromium for the browser-side clients of mrosd.web (their npm packages
# come from tests/web/package-lock.json); actionlib, tf2_ros and dynamic_reconfigure as the partners of
# mrosd.actions, mrosd.tf and mrosd.reconfigure (dynamic_reconfigure's .msg files come in its -dev package).
# mrosd itself needs none of these (python3-venv only to be installed into a venv).
set -euo pipefail
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
# Debian's npm conflicts with a nodejs that bundles its own npm (NodeSource's, as on these machines): ask for it
# only where no npm came with node.
NPM=""
command -v npm >/dev/null 2>&1 || NPM="npm"
$SUDO apt-get update -q
$SUDO apt-get install -y -q \
    python3-venv \
    python3-rospy python3-rostopic python3-rosnode python3-rosparam python3-rosmaster python3-rosservice \
    python3-genmsg python3-genpy python3-std-msgs python3-sensor-msgs python3-geometry-msgs python3-nav-msgs \
    ros-core libroscpp-dev libstd-msgs-dev libsensor-msgs-dev libgeometry-msgs-dev \
    ros-std-msgs ros-geometry-msgs ros-sensor-msgs ros-rosgraph-msgs ros-actionlib-msgs ros-diagnostic-msgs \
    ros-nav-msgs ros-shape-msgs ros-stereo-msgs ros-trajectory-msgs ros-visualization-msgs ros-tf2-msgs \
    ros-map-msgs ros-std-srvs python3-std-srvs \
    python3-actionlib python3-tf2-ros python3-dynamic-reconfigure libdynamic-reconfigure-config-init-mutex-dev \
    g++ cmake pkg-config iproute2 procps \
    nodejs $NPM chromium
# The real WebSocket clients the tests drive (@foxglove/ws-protocol, ...), exactly as locked.
npm ci --prefix "$(dirname "$0")/../tests/web" --no-audit --no-fund
