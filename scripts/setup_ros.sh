#!/usr/bin/env bash
# Set up .venv-ros, the ROS 2 environment (used by `run.sh --backend ros2`, `ros_cell.sh` and the
# test suite's ros lane): armwarden with the extras dev,can,ros, ROS 2 Jazzy's rclpy wheels from
# PyPI pinned by constraints/ros.txt, then control_msgs, controller_manager_msgs and tf2_msgs
# built from ros/interfaces/ (needs cmake and a C++ compiler; about a minute and a half the first
# time). A venv of its own: the ROS wheels re-execute every interpreter of their venv with ROS's
# libraries on LD_LIBRARY_PATH, which the main venv's Pinocchio and MuJoCo must not see.
# Quick and offline when nothing changed (both steps keep a hash of what they installed).
# Everything it says goes to stderr: run.sh's stdout is the MCP channel.
set -euo pipefail
cd "$(dirname "$0")/.."
ARMWARDEN_VENV=.venv-ros ARMWARDEN_EXTRAS=dev,can,ros ARMWARDEN_CONSTRAINTS=constraints/ros.txt \
  bash scripts/bootstrap.sh >&2
.venv-ros/bin/python scripts/build_ros_interfaces.py -j2 >&2
