#!/usr/bin/env bash
# Set up .venv and .venv-ros (extras dev,can,ros pinned by constraints/ros.txt, then the
# control_msgs/controller_manager_msgs/tf2_msgs interfaces built into it), then run the whole test
# suite as three lanes, one after the other, each logging to build/test-logs/ (printed as each lane
# ends); fails if a set-up step fails, or any lane fails or collects no test:
#
#   realtime  first and alone on the machine: the tests of `tests/` that run the CAN emulator's
#          wall-clock physics and servo loop (ARMWARDEN_TEST_REALTIME=only, see tests/conftest.py),
#          on one worker. Beside other test processes a starved servo thread fails closed (an RX
#          timeout fault, a torque estimate off by a 50 ms stall) where a quiet one passes; they
#          keep about half a core busy, so alone they cost about two minutes.
#   tests  then the rest of `tests/` in .venv (no ROS), on ARMWARDEN_TEST_WORKERS pytest-xdist
#          workers (default 2)
#   ros    last, `tests_ros/` and the scenario suite on the ros2 backend only
#          (ARMWARDEN_HARNESS_BACKENDS=ros2, see tests/server/harness.py), on ARMWARDEN_ROS_WORKERS
#          workers (default 1), each on a ROS domain of its own (`-p tests_ros.domains`), with
#          `-p tests_ros.no_skips`: a skipped test there is a failure.
#
# The suite is CPU-bound on this machine's two cores (each test process with the daemons it
# starts keeps about 1.6 cores busy): more workers do not make it faster, and past one per core
# they starve servo and monitor threads of the interpreter (a fake's wrench 0.51 s old beside two
# CPU hogs). Every test is independent of the others and of their order; the counts are settable.
#
# The ROS wheels' .pth re-executes every interpreter of their venv with ROS's lib/ on
# LD_LIBRARY_PATH, hence a venv of their own, away from the main venv's Pinocchio and MuJoCo.
# DDS stays on this host: the ros lane runs with a random ROS_DOMAIN_ID and
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
#
# Extra arguments go to every pytest run, e.g. `bash scripts/test.sh -m slow` for the slow soak
# tests; with extra arguments a lane they leave without tests passes (without, it fails).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
# the ROS venv and its interfaces before the lanes start, not inside the ros lane: building them
# keeps both cores busy for minutes, and the realtime lane needs the machine to itself
bash scripts/setup_ros.sh
export PYTHONHASHSEED=0
logs=build/test-logs
mkdir -p "$logs"
rm -f "$logs"/*.log "$logs"/*.rc

lane_realtime() {
  ARMWARDEN_TEST_REALTIME=only .venv/bin/python -m pytest -m "not slow" -n 1 "$@" tests
}

lane_tests() {
  ARMWARDEN_TEST_REALTIME=skip .venv/bin/python -m pytest -m "not slow" -n "${ARMWARDEN_TEST_WORKERS:-2}" --dist worksteal "$@" tests
}

lane_ros() {
  ROS_DOMAIN_ID="$((RANDOM % 100 + 1))" ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ARMWARDEN_HARNESS_BACKENDS=ros2 \
    PYTHONPATH="$PWD" .venv-ros/bin/python -m pytest -m "not slow" -p tests_ros.domains -p tests_ros.no_skips \
    -n "${ARMWARDEN_ROS_WORKERS:-1}" --dist worksteal "$@" tests_ros tests/scenarios tests/backends/test_harness_backends.py
}

# the lane's log, then whether it failed (an exit status, or no test collected without arguments)
report() {
  local lane="$1" status
  status="$(cat "$logs/$lane.rc")"
  echo "======================== lane $lane ($logs/$lane.log) ========================"
  cat "$logs/$lane.log"
  # pytest exits 5 when it collected no test: a failure of this script, unless arguments filtered it
  if [ "$status" -eq 5 ] && [ "$ARGC" -gt 0 ]; then
    echo "test.sh: lane $lane collected no test with the arguments given"
  elif [ "$status" -eq 5 ]; then
    echo "test.sh: lane $lane collected no test" >&2; failed=1
  elif [ "$status" -ne 0 ]; then
    echo "test.sh: lane $lane failed (exit $status)" >&2; failed=1
  fi
}
ARGC=$#
failed=0

run_lane() {
  local lane="$1"; shift
  local status=0; SECONDS=0; "lane_$lane" "$@" >"$logs/$lane.log" 2>&1 || status=$?
  echo "lane $lane: exit $status after ${SECONDS} s" >>"$logs/$lane.log"; echo "$status" >"$logs/$lane.rc"
}

# one lane after the other, each in the foreground: beside each other the tests and ros lanes ran
# three test processes on two cores, and their starved servo and monitor threads failed closed
for lane in realtime tests ros; do
  ( run_lane "$lane" "$@" )
  report "$lane"
done
echo "test.sh: $(tail -qn1 "$logs/realtime.log" "$logs/tests.log" "$logs/ros.log" | paste -sd';' - | sed 's/;/; /g')"
exit "$failed"
