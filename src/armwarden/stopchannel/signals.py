"""SIGUSR1 → e-stop: for a physical button wired to a script, or `kill -USR1 <pid>`.

Python runs signal handlers on the main thread, which is also the event loop's thread; a handler
that did the stop there would wait its turn behind whatever the loop is running. So the handler
does nothing but set an event, and a thread of our own waits for it and calls the same
thread-safe latch-and-stop as the stop channel (see docs/architecture.md, "Independent stop
channel"). The handler never takes a lock the interrupted code might hold: it only sets a
`threading.Event` no one else sets.

``armwarden estop --pid P --reason R`` writes its reason to a file beside the signal
(`armwarden.stopchannel.reasons`, which says why a file); the thread takes it into the audit
record only after the stop is issued, so the stop never waits for or depends on it. A stop takes
only the reasons whose signal was sent before the thread woke for it and after it woke for the
previous stop (`reasons` says why that time and not the file's): one handed over while an earlier
stop is still being issued is the next stop's.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType

from armwarden.stopchannel.reasons import discard_reasons, take_reasons
from armwarden.stopchannel.server import ChannelStop

logger = logging.getLogger(__name__)

#: (reason, principal) → e-stop event number; the stop channel's `latch_and_stop`
LatchAndStop = Callable[[str, str], int]

SIGNAL_PRINCIPAL = "signal:SIGUSR1"


class SignalStop:
    """Turns each SIGUSR1 into one e-stop on a dedicated thread; `close()` restores the old handler."""

    def __init__(self, latch_and_stop: LatchAndStop, *, on_event: Callable[[ChannelStop], None] | None = None,
                 signum: int = signal.SIGUSR1, reason_directory: Path | None = None) -> None:
        """`reason_directory`: where ``armwarden estop --pid`` writes reasons (None: its default)."""
        self._latch_and_stop = latch_and_stop
        self._reason_directory = reason_directory
        self._on_event = on_event
        self._signum = signum
        self._raised = threading.Event()
        self._closing = False
        self._thread: threading.Thread | None = None
        self._started_ns = 0  # time.monotonic_ns() before the handler was installed
        self._previous: Callable[[int, FrameType | None], object] | int | None = None

    def start(self) -> SignalStop:
        """Install the handler (main thread only, as Python requires) and start the stop thread."""
        if self._thread is not None:
            raise RuntimeError("SignalStop already started")
        self._started_ns = time.monotonic_ns()  # every signal this handler sees was sent after it
        if self._signum == signal.SIGUSR1:  # left by an earlier process with this id: not for our stops
            discard_reasons(directory=self._reason_directory)
        self._thread = threading.Thread(target=self._run, name="armwarden-sigusr1", daemon=True)
        self._thread.start()
        self._previous = signal.signal(self._signum, self._handle)
        return self

    def close(self) -> None:
        """Restore the previous handler and stop the thread. Idempotent."""
        if self._thread is None or self._closing:
            return
        self._closing = True
        if self._previous is not None:
            signal.signal(self._signum, self._previous)
        self._raised.set()
        self._thread.join(timeout=5.0)

    def __enter__(self) -> SignalStop:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self._raised.set()

    def _run(self) -> None:
        previous_woke_ns = self._started_ns
        while True:
            self._raised.wait()
            self._raised.clear()
            woke_ns = time.monotonic_ns()  # after clear(): every signal this stop answers was sent before
            if self._closing:
                return
            self._stop(previous_woke_ns, woke_ns)
            previous_woke_ns = woke_ns

    def _stop(self, previous_woke_ns: int, woke_ns: int) -> None:
        name = signal.Signals(self._signum).name
        received = time.monotonic()
        try:
            number = self._latch_and_stop(f"{name} received", SIGNAL_PRINCIPAL)
        except Exception as exc:
            logger.critical("%s: the e-stop may NOT have been issued: %s", name, exc, exc_info=True)
            reason = self._reason(name, previous_woke_ns, woke_ns)
            self._report(ChannelStop(SIGNAL_PRINCIPAL, reason, "signal", None, None, str(exc)))
            return
        issued_ms = round((time.monotonic() - received) * 1e3, 4)
        reason = self._reason(name, previous_woke_ns, woke_ns)  # only now: the stop never waits for the reason
        logger.warning("%s: e-stop #%d latched and the robot stopped (%s)", name, number, reason)
        self._report(ChannelStop(SIGNAL_PRINCIPAL, reason, "signal", number, issued_ms, None))

    def _reason(self, name: str, previous_woke_ns: int, woke_ns: int) -> str:
        """The reasons ``armwarden estop --pid`` wrote for this process with signals sent between
        the two wake-ups, or "<signal> received"."""
        if self._signum != signal.SIGUSR1:
            return f"{name} received"
        try:
            text = take_reasons(directory=self._reason_directory, signalled_from_ns=previous_woke_ns,
                                signalled_before_ns=woke_ns)
        except Exception:  # take_reasons never raises; the record must be written all the same
            logger.exception("reading the reason of the %s e-stop failed", name)
            text = None
        return text or f"{name} received"

    def _report(self, stop: ChannelStop) -> None:
        if self._on_event is None:
            return
        try:
            self._on_event(stop)
        except Exception:
            logger.exception("recording the %s e-stop failed", signal.Signals(self._signum).name)


__all__ = ["SIGNAL_PRINCIPAL", "SignalStop"]
