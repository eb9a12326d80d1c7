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
        idle            that goal is over (the server said so)
        bye             the daemon closes normally: exit (cancelling a goal still current)
    guardian -> daemon (a copy of its stdout; stdout itself is pointed at stderr, where whatever
    C libraries print belongs):
        ready           its node is up; the watch has begun
        watching        its client has found the action's cancel service: it can cancel now
                        (the daemon sends no goal before this; DDS discovery may take a while)
        alive           every `ALIVE_PERIOD_S` from the watch loop (the daemon faults on silence)
        cancelled WHY   it cancelled the current goal on its own (the cell confirmed), and why
        failed to cancel (DETAIL): WHY
                        it tried and the cell did not confirm (no service, no answer, refused)

It cancels the current goal (by id: other clients' goals are not its business) when its stdin
ends (the daemon died or closed the pipe: the kernel closes it, so a `kill -9` is seen at once),
and when nothing came for `deadline_s` while a goal is current (the daemon hangs, or is stopped
with SIGSTOP). Silence is `select`'s verdict, measured by the kernel, so a guardian that was
itself descheduled finds the beats waiting and does not blame its own stall on the daemon. Each
cancel waits for the cell's answer; a goal the cell says is already over is no news (no fault),
a cancel that did not get through is reported as such and tried again while the silence lasts.

It runs in a session of its own and ignores SIGINT, SIGTERM, SIGHUP and SIGTSTP: a terminal's
Ctrl-C or hang-up, or a service manager's stop, reaches the daemon's process group, and the
guardian must outlive the daemon's end to cancel what the daemon could not. Only its pipe ends it
(or SIGKILL).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import NoReturn, TextIO

import rclpy.node
from action_msgs.srv import CancelGoal

from armwarden.backends.ros2.bridge import RosBridge

logger = logging.getLogger("armwarden.ros2.guardian")

#: how long a cancel waits for the cancel service to be discovered [s]
SERVICE_TIMEOUT_S = 1.0
#: how long the guardian waits for the cell to answer a cancel before exiting [s]
ANSWER_TIMEOUT_S = 2.0
#: how often the guardian says "alive" to the daemon [s]
ALIVE_PERIOD_S = 0.1
#: how long the guardian gives its node to leave the DDS domain before it exits anyway [s]
CLOSE_TIMEOUT_S = 2.0


def cancel_request(goal_id: bytes) -> CancelGoal.Request:
    """A request to cancel the goal `goal_id` only (a zero stamp: no "and every older goal")."""
    request = CancelGoal.Request()
    request.goal_info.goal_id.uuid = list(goal_id)
    return request


class Guardian:
    """The watch: lines from the daemon in, a cancel out when the daemon is gone or silent, and
    "alive" back to the daemon every `ALIVE_PERIOD_S` (so a guardian that stalls is seen)."""

    def __init__(self, node: rclpy.node.Node, action: str, deadline_s: float, report: TextIO) -> None:
        self._report = report
        self._client = node.create_client(CancelGoal, f"{action}/_action/cancel_goal")  # made before the spin
        self._deadline_s = deadline_s
        self._goal: bytes | None = None
        self._silence_handled = False  # the current goal was cancelled (or found over) for this silence
        self._last_alive = 0.0
        self._last_heard = time.monotonic()  # when the daemon last wrote anything
        self._service_seen = False  # its client has matched the cell's cancel service

    def watch(self, fd: int) -> str:
        """Until the daemon says bye or goes: returns why the watch ended. Silence is what `select`
        says, measured by the kernel: a guardian that was itself descheduled finds the daemon's
        beats waiting when it runs again, and does not take its own stall for the daemon's."""
        pending = b""
        while True:
            self._say_alive()
            if not self._service_seen and self._client.service_is_ready():
                self._service_seen = True
                self._tell("watching")  # the daemon sends no goal before this
            ready, _, _ = select.select([fd], [], [], min(self._deadline_s, ALIVE_PERIOD_S))
            if not ready:
                if time.monotonic() - self._last_heard >= self._deadline_s:
                    self._on_silence()
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                if self._goal is not None:
                    self._cancel("the daemon's pipe closed (it exited or was killed)")
                return "end of input"
            self._last_heard = time.monotonic()
            pending += chunk
            *lines, pending = pending.split(b"\n")
            for line in lines:
                command, _, argument = line.decode("ascii", "replace").strip().partition(" ")
                if command == "bye":
                    if self._goal is not None:  # the daemon's own stop should have ended it: once more
                        self._cancel("the daemon closed while a goal was current")
                    return "bye"
                if command == "goal":
                    self._goal, self._silence_handled = bytes.fromhex(argument), False
                elif command == "idle":
                    self._goal = None

    def _say_alive(self) -> None:
        now = time.monotonic()
        if now - self._last_alive >= ALIVE_PERIOD_S:
            self._last_alive = now
            self._tell("alive")

    def _on_silence(self) -> None:
        """The daemon silent past the deadline with a goal current: cancel it, once per goal, and
        again on a later silence if the cancel did not get through."""
        if self._goal is None or self._silence_handled:
            return
        outcome = self._cancel(f"the daemon was silent for {self._deadline_s:g} s")
        self._silence_handled = outcome != "failed"

    def _cancel(self, why: str) -> str:
        """Ask the cell to cancel the current goal and wait for its answer: "cancelled" (told to the
        daemon, which latches), "over" (the goal had already ended: nothing to tell), or "failed"
        (no cancel service, no answer, refused: told to the daemon as a failed cancel)."""
        goal = self._goal
        assert goal is not None
        outcome, detail = "failed", "no cancel service"
        # a goal was sent, so the server was there; discovery of its cancel service may lag behind
        if self._client.wait_for_service(timeout_sec=SERVICE_TIMEOUT_S):
            future = self._client.call_async(cancel_request(goal))
            deadline = time.monotonic() + ANSWER_TIMEOUT_S
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.002)
            outcome, detail = _outcome(goal, future.result() if future.done() else None)
        if outcome == "cancelled":
            self._tell(f"cancelled {why}")
            logger.warning("armwarden guardian: cancelled goal %s: %s", goal.hex(), why)
        elif outcome == "failed":
            self._tell(f"failed to cancel ({detail}): {why}")
            logger.error("armwarden guardian: could not cancel goal %s (%s): %s", goal.hex(), detail, why)
        return outcome

    def _tell(self, line: str) -> None:
        with contextlib.suppress(OSError):  # a dead daemon's end of the pipe is closed
            print(line, file=self._report, flush=True)


def _outcome(goal: bytes, response: CancelGoal.Response | None) -> tuple[str, str]:
    """What the cell's answer to a cancel of `goal` says (see `Guardian._cancel`)."""
    if response is None:
        return "failed", f"no answer within {ANSWER_TIMEOUT_S:g} s"
    if any(bytes(info.goal_id.uuid) == goal for info in response.goals_canceling):
        return "cancelled", ""
    if response.return_code in (CancelGoal.Response.ERROR_UNKNOWN_GOAL_ID, CancelGoal.Response.ERROR_GOAL_TERMINATED):
        return "over", ""
    return "failed", f"the cell answered return code {response.return_code}"


def main(argv: Sequence[str] | None = None) -> NoReturn:
    parser = argparse.ArgumentParser(prog="armwarden-ros2-guardian",
                                     description="Cancel the daemon's trajectory goal if the daemon dies or hangs.")
    parser.add_argument("--action", required=True, help="the FollowJointTrajectory action the daemon sends goals to")
    parser.add_argument("--deadline-s", type=float, required=True, help="silence that counts as a hung daemon [s]")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGTSTP):
        signal.signal(number, signal.SIG_IGN)  # see the module docstring: only the pipe ends the watch
    # the pipe to the daemon is a copy of stdout; stdout itself becomes stderr, so what DDS and other
    # C libraries print there (a shared-memory segment that cannot be made, say) is logged, not read
    report = os.fdopen(os.dup(sys.stdout.fileno()), "w", buffering=1, encoding="utf-8")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    bridge = RosBridge(f"armwarden_guardian_{os.getpid()}", args.domain_id)
    made: list[Guardian] = []
    bridge.start(lambda: made.append(Guardian(bridge.node, args.action, args.deadline_s, report)))
    code = 0
    try:
        print("ready", file=report, flush=True)
        made[0].watch(sys.stdin.fileno())
    except BaseException:
        logger.exception("armwarden guardian: the watch failed")
        code = 1
    # Leave the DDS domain properly (a participant that just vanishes stays matched by the others
    # until its lease runs out, slowing their discovery), but for a bounded time: destroying the
    # node's FastDDS participant can spin for ever waiting on its listener (seen here: a guardian at
    # 100 % of a core for 20 minutes after its daemon was killed). Every cancel has had its answer.
    closing = threading.Thread(target=bridge.close, name="armwarden-guardian-close", daemon=True)
    closing.start()
    closing.join(CLOSE_TIMEOUT_S)
    logging.shutdown()
    with contextlib.suppress(OSError):
        report.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
