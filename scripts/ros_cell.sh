#!/usr/bin/env bash
# The fake FR3 cell (tests_ros/cell.py: real rclpy endpoints as a ros2_control FR3 with a Franka
# Hand and a scene camera offers them) for `bash scripts/run.sh --backend ros2 --backend-config
# examples/ros2_fr3.yaml` to drive. Sets up .venv-ros first (scripts/setup_ros.sh). DDS: the
# daemon's defaults where the environment sets nothing (ROS_DOMAIN_ID 0,
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), named on stderr; start the daemon with the same.
# Extra arguments go to the cell, e.g. --table-height 0.1 (a virtual table the wrench feels).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_ros.sh
PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" exec .venv-ros/bin/python -m tests_ros.cell "$@"
