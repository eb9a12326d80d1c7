#!/usr/bin/env bash
# The main job: set up, then run the ArmWarden daemon on stdio with the fake FR3 backend and the
# bundled FR3 policy (extra arguments are passed to `armwarden serve`, e.g. --transport http).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/armwarden serve "$@"
