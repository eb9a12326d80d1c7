#!/usr/bin/env bash
# The main job: set up, then run the ArmWarden daemon on stdio with the fake FR3 backend and the
# bundled FR3 policy (extra arguments are passed to `armwarden serve`, e.g. --transport http).
# With `--backend ros2` it sets up and serves from .venv-ros (scripts/setup_ros.sh) instead of
# .venv: the ROS wheels need a venv of their own. Set-up output goes to stderr (stdout is MCP's).
set -euo pipefail
cd "$(dirname "$0")/.."
backend=fake
previous=""
for arg in "$@"; do
  case "$arg" in --backend=*) backend="${arg#--backend=}" ;; esac
  if [ "$previous" = "--backend" ]; then backend="$arg"; fi
  previous="$arg"
done
if [ "$backend" = ros2 ]; then
  bash scripts/setup_ros.sh
  exec .venv-ros/bin/armwarden serve "$@"
fi
bash scripts/bootstrap.sh >&2
exec .venv/bin/armwarden serve "$@"
