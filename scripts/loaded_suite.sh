#!/usr/bin/env bash
# Run the whole suite (scripts/test.sh) RUNS times in a row (default 5) while HOGS busy loops
# (default 2, one per core here) run beside it, and print each run's exit status and time: the
# check that no test depends on timing luck or a quiet machine (issue 31). Stops at the first
# failing run and keeps its lane logs in build/test-logs/; prints a summary line per run either way.
#
#   bash scripts/loaded_suite.sh [RUNS] [HOGS]
set -uo pipefail
cd "$(dirname "$0")/.."
runs="${1:-5}"
hogs="${2:-2}"
hog_pids=()
stop_hogs() { for pid in "${hog_pids[@]}"; do kill "$pid" 2>/dev/null || true; done; }
trap stop_hogs EXIT INT TERM
for _ in $(seq "$hogs"); do
  ( while :; do :; done ) &
  hog_pids+=($!)
done
mkdir -p build
summary=build/loaded-suite.txt
: >"$summary"
for run in $(seq "$runs"); do
  SECONDS=0
  bash scripts/test.sh >"build/loaded-suite-run$run.log" 2>&1
  status=$?
  line="run $run/$runs beside $hogs CPU hogs: exit $status after ${SECONDS} s ($(tail -n1 "build/loaded-suite-run$run.log"))"
  echo "$line" | tee -a "$summary"
  if [ "$status" -ne 0 ]; then
    echo "loaded_suite.sh: run $run failed; its log: build/loaded-suite-run$run.log" >&2
    exit "$status"
  fi
done
echo "loaded_suite.sh: $runs of $runs runs green beside $hogs CPU hogs" | tee -a "$summary"
