#!/usr/bin/env bash
# Set up, then run the whole test suite (tests/, and tests_ros/ when it has tests).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for the slow soak tests.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
export PYTHONHASHSEED=0
status=0
.venv/bin/python -m pytest -m "not slow" "$@" tests || status=$?
# pytest exits 5 when it collected no test: that is a failure of this script, not a pass
if [ "$status" -eq 5 ]; then echo "test.sh: no tests were collected" >&2; exit 1; fi
exit "$status"
