"""The daemon's end of the ROS 2 guardian's pipe (`armwarden.backends.ros2.guardian` has the
protocol): start the guardian process, beat from a thread of its own, tell it each goal, and read
what it says.

A guardian that cancelled a goal on its own (the daemon was silent past the deadline) or that is
gone is a fault: `on_fault` is called with the reason (the backend stops the arm and reports it;
the Guard latches its e-stop). A gone guardian is one for good: `problem` names it from then on,
so no goal is sent without a guardian watching. Closing says "bye" (the guardian then exits by itself).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence

from armwarden.core.errors import BackendError

logger = logging.getLogger(__name__)

#: how often the daemon writes "beat" to the guardian [s]
BEAT_PERIOD_S = 0.05
#: the guardian says "alive" every 0.1 s; this long without a word it counts as stuck [s]
SILENT_GUARDIAN_S = 2.0

class GuardianLink:
    """The guardian process for the trajectory action `action`, from `start` to `close`."""

    def __init__(self, action: str, deadline_s: float, domain_id: int | None, on_fault: Callable[[str], None], *,
                 command: Sequence[str] | None = None) -> None:
        """`command`: another program that speaks the protocol instead of the guardian (tests)."""
        self._command = [sys.executable, "-m", "armwarden.backends.ros2.guardian", "--action", action,
                         "--deadline-s", f"{deadline_s:g}"]
        if domain_id is not None:
            self._command += ["--domain-id", str(domain_id)]
        if command is not None:
            self._command = list(command)
        self._on_fault = on_fault
        self._process: subprocess.Popen[str] | None = None
        self._write_lock = threading.Lock()
        self._closing = threading.Event()
        self._problem: str | None = None
        self._last_alive = time.monotonic()  # the guardian's latest line (it says "alive" every 0.1 s)
        self._watching = threading.Event()  # it has found the cancel service

    @property
    def problem(self) -> str | None:
        """Why the guardian no longer watches (None: it does): it exited, stopped reading its pipe,
        or has said nothing (not even "alive") for `SILENT_GUARDIAN_S`."""
        if self._problem is not None:
            return self._problem
        quiet_s = time.monotonic() - self._last_alive
        if self._process is not None and not self._closing.is_set() and quiet_s > SILENT_GUARDIAN_S:
            return f"the ROS 2 guardian process has said nothing for {quiet_s:.1f} s (stuck or stopped)"
        return None

    @property
    def process(self) -> subprocess.Popen[str] | None:
        """The guardian process, once started."""
        return self._process

    def start(self, timeout_s: float) -> None:
        """Blocking: start the guardian and wait (at most `timeout_s`) for its "ready"."""
        # a session of its own: a terminal's hang-up or Ctrl-C, or a stop of the daemon's process
        # group, must not end the guardian with the daemon (it ignores those signals too)
        process = self._process = subprocess.Popen(self._command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                                   text=True, bufsize=1, start_new_session=True)
        assert process.stdout is not None
        answer: list[str] = []
        reader = threading.Thread(target=self._wait_ready, args=(answer,), name="armwarden-guardian-ready", daemon=True)
        reader.start()
        reader.join(timeout_s)
        self._last_alive = time.monotonic()
        if not answer or answer[-1] != "ready":
            self._kill()
            said = answer[-1] if answer else f"nothing within {timeout_s:g} s"
            raise BackendError(f"the ROS 2 guardian process did not start ({said}); without it a goal would run "
                               "on if the daemon died, so nothing is sent")
        assert process.stdin is not None
        os.set_blocking(process.stdin.fileno(), False)  # see `_send`
        threading.Thread(target=self._beat, name="armwarden-guardian-beat", daemon=True).start()
        threading.Thread(target=self._listen, name="armwarden-guardian-listen", daemon=True).start()

    def _wait_ready(self, answer: list[str]) -> None:
        """Reader: lines until "ready" or the end (the last one read lands in `answer`)."""
        assert self._process is not None and self._process.stdout is not None
        for line in self._process.stdout:
            answer.append(line.strip())
            if answer[-1] == "ready":
                return
        answer.append(f"it exited after saying {answer[-1]!r}" if answer else "it exited")

    def goal(self, goal_id: bytes) -> None:
        """Before a goal is sent: the guardian cancels it if the daemon goes. `BackendError` (and the
        goal is not sent) when the guardian is not watching or the line did not reach it."""
        if self.problem is not None or not self._send(f"goal {goal_id.hex()}"):
            raise BackendError(f"{self.problem or 'the ROS 2 guardian process could not be told the goal'}; "
                               "nothing was sent")

    def idle(self) -> None:
        """The goal is over."""
        self._send("idle")

    def wait_watching(self, timeout_s: float) -> bool:
        """Blocking: whether the guardian has found the action's cancel service (waiting up to
        `timeout_s`). Its node discovers the cell on its own, and a goal it cannot cancel is not
        watched: the backend sends none before this."""
        return self._watching.wait(timeout_s)

    def expect_exit(self) -> None:
        """The daemon is closing: the guardian's exit from now on is no fault (a stop of the whole
        process group may reach it before "bye" does)."""
        self._closing.set()

    def close(self) -> None:
        """Say "bye": the guardian exits by itself, cancelling nothing. Not waited for: the daemon's
        own shutdown must not wait on another process's (an MCP client gives a closing server
        about two seconds before it kills it)."""
        self._closing.set()
        self._send("bye")

    def _send(self, line: str) -> bool:
        """Never blocks (`goal` runs under the arm's motion lock, which every stop takes): the pipe
        is non-blocking and a line is far below its atomic size, so it goes whole or not at all. A
        pipe full of unread lines means a guardian that no longer reads (stopped, stuck): a fault
        for good, reported from a thread of its own (the reporting stops the arm: the motion lock)."""
        process = self._process
        if process is None or process.stdin is None:
            return False
        with self._write_lock:
            try:
                os.write(process.stdin.fileno(), (line + "\n").encode())
                return True
            except BlockingIOError:
                if self._problem is None:
                    self._problem = "the ROS 2 guardian process stopped reading its pipe; goals would run on if the daemon died"
                    threading.Thread(target=self._report, args=(self._problem,), name="armwarden-guardian-fault",
                                     daemon=True).start()
            except (OSError, ValueError):  # the guardian is gone: `_listen` finds its end and reports it
                pass
        return False

    def _report(self, problem: str) -> None:
        logger.error("ros2 backend: %s", problem)
        self._on_fault(problem)

    def _beat(self) -> None:
        while not self._closing.wait(BEAT_PERIOD_S):
            self._send("beat")

    def _listen(self) -> None:
        """What the guardian says, until its output ends (it exited): each is a fault."""
        process = self._process
        assert process is not None and process.stdout is not None
        for line in process.stdout:  # the guardian writes only its protocol here (its stdout is its stderr)
            self._last_alive = time.monotonic()
            if line.strip() == "watching":
                self._watching.set()
            elif line.startswith("cancelled "):  # it stopped the arm behind the daemon's back, and watches on
                self._report(f"the ROS 2 guardian process cancelled the goal: {line.strip()[len('cancelled '):]}")
            elif line.startswith("failed to cancel"):  # it tried, and the cell did not confirm
                self._report(f"the ROS 2 guardian process {line.strip()}")
        if not self._closing.is_set():
            code = process.wait()
            self._problem = f"the ROS 2 guardian process exited (code {code}); goals would run on if the daemon died"
            self._report(self._problem)

    def _kill(self) -> None:
        if self._process is not None and self._process.poll() is None:
            self._process.kill()
            self._process.wait()


__all__ = ["GuardianLink"]
