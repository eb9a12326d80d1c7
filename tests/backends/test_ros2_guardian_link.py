"""The daemon's end of the ROS 2 guardian's pipe, against stand-in programs that speak (or break)
the protocol: no ROS needed. The guardian itself, with ROS: tests_ros/test_ros2_guardian.py and
tests_ros/test_daemon_ros2.py."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator

import pytest

from armwarden.backends.ros2.guardian_link import GuardianLink
from armwarden.core.errors import BackendError

GOAL_ID = bytes(range(16))


class Faults:
    """What the link reported, with an event per report."""

    def __init__(self) -> None:
        self.reported: list[str] = []
        self.event = threading.Event()

    def __call__(self, problem: str) -> None:
        self.reported.append(problem)
        self.event.set()

    def wait(self) -> list[str]:
        assert self.event.wait(10.0), "no fault was reported"
        return self.reported


def stand_in(script: str) -> list[str]:
    return [sys.executable, "-c", f"import sys, time\n{script}"]


#: what a healthy guardian says after its other lines: "alive" every 0.1 s (it never reads its pipe)
ALIVE = "\nfor _ in range(600):\n    print('alive', flush=True)\n    time.sleep(0.1)"


@pytest.fixture
def faults() -> Faults:
    return Faults()


@pytest.fixture
def started(request: pytest.FixtureRequest, faults: Faults) -> Iterator[GuardianLink]:
    link = GuardianLink("/arm/follow_joint_trajectory", 0.5, None, faults, command=stand_in(request.param))
    link.start(10.0)
    yield link
    link.close()
    if link.process is not None and link.process.poll() is None:
        link.process.kill()
        link.process.wait()


READY_THEN_ALIVE = "print('ready', flush=True)" + ALIVE


@pytest.mark.parametrize("started", [READY_THEN_ALIVE], indirect=True)
def test_a_guardian_that_stops_reading_is_a_fault_for_good_and_a_write_never_blocks(started: GuardianLink,
                                                                                     faults: Faults) -> None:
    refused = None
    for _ in range(100_000):  # a 64 KiB pipe holds a few thousand goal lines
        try:
            started.goal(GOAL_ID)  # returns at once even with the pipe full: it runs under the motion lock
        except BackendError as exc:  # no goal is sent without a watch
            refused = exc
            break
    assert refused is not None and "stopped reading its pipe" in str(refused)
    assert started.problem is not None and "stopped reading its pipe" in started.problem
    assert faults.wait() == [started.problem]


@pytest.mark.parametrize("started", ["print('ready', flush=True)\nsys.exit(3)"], indirect=True)
def test_a_guardian_that_exits_is_a_fault_for_good(started: GuardianLink, faults: Faults) -> None:
    [problem] = faults.wait()
    assert "exited (code 3)" in problem and started.problem == problem


@pytest.mark.parametrize("started", [
    "print('ready', flush=True)\nprint('cancelled the daemon was silent for 0.5 s', flush=True)" + ALIVE,
], indirect=True)
def test_a_cancel_of_its_own_is_reported_and_the_guardian_watches_on(started: GuardianLink, faults: Faults) -> None:
    [problem] = faults.wait()
    assert problem == "the ROS 2 guardian process cancelled the goal: the daemon was silent for 0.5 s"
    assert started.problem is None


@pytest.mark.parametrize("started", ["print('a DDS library says something', flush=True)\nprint('ready', flush=True)"
                                     + ALIVE], indirect=True)
def test_lines_before_ready_are_not_taken_for_the_answer(started: GuardianLink, faults: Faults) -> None:
    assert started.problem is None and not faults.reported


def test_a_guardian_that_never_says_ready_fails_the_start_naming_what_it_said(faults: Faults) -> None:
    link = GuardianLink("/arm/follow_joint_trajectory", 0.5, None, faults,
                        command=stand_in("print('no cancel service', flush=True)"))
    with pytest.raises(BackendError, match=r"did not start \(it exited after saying 'no cancel service'\)"):
        link.start(10.0)
    assert link.process is not None and link.process.poll() is not None


@pytest.mark.parametrize("started", ["print('ready', flush=True)\nprint('failed to cancel (no cancel service): the "
                                     "daemon was silent for 0.5 s', flush=True)" + ALIVE], indirect=True)
def test_a_cancel_that_did_not_get_through_is_reported(started: GuardianLink, faults: Faults) -> None:
    [problem] = faults.wait()
    assert problem.startswith("the ROS 2 guardian process failed to cancel (no cancel service)")


@pytest.mark.parametrize("started", ["print('ready', flush=True)\ntime.sleep(60)"], indirect=True)
def test_a_guardian_that_says_nothing_is_not_watching_and_no_goal_is_sent(started: GuardianLink) -> None:
    deadline = time.monotonic() + 10.0
    while started.problem is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert started.problem is not None and "has said nothing" in started.problem
    with pytest.raises(BackendError, match=r"has said nothing.*nothing was sent"):
        started.goal(GOAL_ID)


@pytest.mark.parametrize("started", ["print('ready', flush=True)\nsys.exit(0)"], indirect=True)
def test_no_goal_is_sent_once_the_guardian_has_exited(started: GuardianLink, faults: Faults) -> None:
    faults.wait()
    with pytest.raises(BackendError, match=r"exited.*nothing was sent"):
        started.goal(GOAL_ID)


@pytest.mark.parametrize("started", ["print('ready', flush=True)\nsys.stdin.readline()\nsys.exit(0)"], indirect=True)
def test_an_exit_the_daemon_expects_is_no_fault(started: GuardianLink, faults: Faults) -> None:
    started.expect_exit()
    started.goal(GOAL_ID)  # the stand-in reads one line and exits
    assert started.process is not None and started.process.wait(timeout=10) == 0
    time.sleep(0.2)  # the listener has seen the end by now; nothing may have been reported
    assert not faults.reported and started.problem is None


@pytest.mark.parametrize("started", ["print('ready', flush=True)\nprint('watching', flush=True)" + ALIVE], indirect=True)
def test_a_guardian_that_found_the_cancel_service_is_watching(started: GuardianLink) -> None:
    assert started.wait_watching(10.0)


@pytest.mark.parametrize("started", [READY_THEN_ALIVE], indirect=True)
def test_a_guardian_that_has_not_found_the_cancel_service_is_not_watching(started: GuardianLink) -> None:
    assert not started.wait_watching(0.3)
