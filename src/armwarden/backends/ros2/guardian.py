"""The ROS 2 guardian: a small process of its own that cancels the daemon's trajectory goal when
the daemon dies, hangs or lets go of it (issue "The arm stays safe when the server does not").

A ros2_control trajectory controller runs an accepted FollowJointTrajectory goal to its end
whatever happens to the node that sent it. If the daemon is killed mid-motion, nothing watches
the force or stops the arm any more; if it hangs, its stops do not go out. The guardian holds its
own rclpy node and a client of the action's cancel service, and the daemon talks to it over a
pipe (`armwarden.backends.ros2.guardian_link` is the daemon's end):

    daemon -> guardian (its stdin), one line each:
        beat            every 50 ms (`guardian_link.BEAT_PERIOD_S`) from a thread of the daemon
        goal HEX        the 16-byte goal id (hex) the daemon is about to send
        idle            that goal is over (ended, cancelled, rejected)
        bye             the daemon closes normally: exit, cancelling nothing
    guardian -> daemon (its stdout):
        ready           its node is up; the watch has begun
        cancelled WHY   it asked the cell to cancel the current goal on its own, and why

It cancels the current goal (by id: other clients' goals are not its business) when its stdin
ends (the daemon died or closed the pipe: the kernel closes it, so a `kill -9` is seen at once),
and when no line came for `deadline_s` (the daemon hangs, or is stopped with SIGSTOP). After a
cancel on end of input it waits for the cell's answer (at most `ANSWER_TIMEOUT_S`), so the
request is out before it exits. A cancel for silence is sent once per goal; the daemon, if it
wakes, reads "cancelled" and latches its e-stop (the arm has been stopped behind its back).

Ctrl-C in a terminal reaches every process of the foreground group: the guardian ignores SIGINT,
so it outlives the daemon's own shutdown (which stops the arm and then says "bye").
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import TextIO

import rclpy.node
from action_msgs.srv import CancelGoal

from armwarden.backends.ros2.bridge import RosBridge

logger = logging.getLogger("armwarden.ros2.guardian")

#: how long a cancel waits for the cancel service to be discovered [s]
SERVICE_TIMEOUT_S = 1.0
#: how long the guardian waits for the cell to answer a cancel before exiting [s]
ANSWER_TIMEOUT_S = 2.0
#: the pipe's end: the reader puts this on the queue when stdin closes
_END = ""


def cancel_request(goal_id: bytes) -> CancelGoal.Request:
    """A request to cancel the goal `goal_id` only (a zero stamp: no "and every older goal")."""
    request = CancelGoal.Request()
    request.goal_info.goal_id.uuid = list(goal_id)
    return request


class Guardian:
    """The watch: lines from the daemon in, a cancel out when the daemon is gone or silent."""

    def __init__(self, node: rclpy.node.Node, action: str, deadline_s: float, report: TextIO) -> None:
        self._report = report
        self._client = node.create_client(CancelGoal, f"{action}/_action/cancel_goal")  # made before the spin
        self._deadline_s = deadline_s
        self._lines: queue.Queue[str] = queue.Queue()
        self._goal: bytes | None = None
        self._cancelled_for_silence = False


    def read(self, stream: object) -> None:
        """Reader thread: every line of `stream` onto the queue, then `_END`."""
        try:
            for line in stream:  # type: ignore[attr-defined]
                self._lines.put(line.strip() or "beat")
        finally:
            self._lines.put(_END)

    def watch(self) -> str:
        """Until the daemon says bye or goes: returns why the watch ended."""
        while True:
            try:
                line = self._lines.get(timeout=self._deadline_s)
            except queue.Empty:
                if self._goal is not None and not self._cancelled_for_silence:
                    self._cancelled_for_silence = True
                    self._cancel(f"the daemon was silent for {self._deadline_s:g} s", wait=False)
                continue
            if line == _END:
                if self._goal is not None:
                    self._cancel("the daemon's pipe closed (it exited or was killed)", wait=True)
                return "end of input"
            command, _, argument = line.partition(" ")
            if command == "bye":
                return "bye"
            if command == "goal":
                self._goal, self._cancelled_for_silence = bytes.fromhex(argument), False
            elif command == "idle":
                self._goal = None

    def _cancel(self, why: str, *, wait: bool) -> None:
        goal = self._goal
        assert goal is not None
        # a goal was sent, so the server was there; discovery of its cancel service may lag behind
        if not self._client.wait_for_service(timeout_sec=SERVICE_TIMEOUT_S):
            logger.error("armwarden guardian: no cancel service for goal %s: %s", goal.hex(), why)
        future = self._client.call_async(cancel_request(goal))
        with contextlib.suppress(OSError):  # a dead daemon's end of the pipe is closed
            print(f"cancelled {why}", file=self._report, flush=True)
        logger.warning("armwarden guardian: cancelled goal %s: %s", goal.hex(), why)
        if wait:
            deadline = time.monotonic() + ANSWER_TIMEOUT_S
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.005)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="armwarden-ros2-guardian",
                                     description="Cancel the daemon's trajectory goal if the daemon dies or hangs.")
    parser.add_argument("--action", required=True, help="the FollowJointTrajectory action the daemon sends goals to")
    parser.add_argument("--deadline-s", type=float, required=True, help="silence that counts as a hung daemon [s]")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the daemon's shutdown stops the arm, then says bye
    # the pipe to the daemon is a copy of stdout; stdout itself becomes stderr, so what DDS and other
    # C libraries print there (a shared-memory segment that cannot be made, say) is logged, not read
    report = os.fdopen(os.dup(sys.stdout.fileno()), "w", buffering=1, encoding="utf-8")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    bridge = RosBridge(f"armwarden_guardian_{os.getpid()}", args.domain_id)
    made: list[Guardian] = []
    bridge.start(lambda: made.append(Guardian(bridge.node, args.action, args.deadline_s, report)))
    guardian = made[0]
    try:
        threading.Thread(target=guardian.read, args=(sys.stdin,), name="armwarden-guardian-input", daemon=True).start()
        print("ready", file=report, flush=True)
        guardian.watch()
        return 0
    finally:
        bridge.close()  # the executor joined before the node goes: a thread left spinning aborts at exit


if __name__ == "__main__":
    sys.exit(main())
