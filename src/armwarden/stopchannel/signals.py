"""SIGUSR1 → e-stop: for a physical button wired to a script, or `kill -USR1 <pid>`.

Python runs signal handlers on the main thread, which is also the event loop's thread; a handler
that did the stop there would wait its turn behind whatever the loop is running. So the handler
does nothing but set an event, and a thread of our own waits for it and calls the same
thread-safe latch-and-stop as the stop channel (see docs/architecture.md, "Independent stop
channel"). The handler never takes a lock the interrupted code might hold: it only sets a
`threading.Event` no one else sets.

``armwarden estop --pid P --reason R`` signals first and then writes its reason to a file
(`armwarden.stopchannel.reasons`, which says why a file), so the stop never waits for the disk.
The stop thread issues the stop and hands it to a second thread, the recorder, which waits for
the reason at most `REASON_GRACE_S` after the stop was issued (ending as soon as one is there)
and then writes the audit record ("SIGUSR1 received" when none came). The stop thread never
waits for the recorder: a stop signalled meanwhile is issued at once.

Which reasons a stop takes: each reason file names the time its command took just before
signalling, and the stop thread notes the same clock when a signal wakes it, after clearing the
signal's flag, so every signal a stop answers was sent before its wake. A stop takes the reasons
signalled after the previous stop's wake and before its own, whenever they were written (during
its grace, or even before it woke); a reason signalled after its wake is the next stop's, even if
written while this stop's record still waits; one that turns up after its stop was recorded is
dropped, not put on a later stop. Signals coalesce: two commands that signal before one wake get
one stop, which takes both reasons ("; "-joined, in signalling order) — the first found ends the
wait, so a second still being written is lost.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from armwarden.stopchannel.reasons import discard_reasons, take_reasons
from armwarden.stopchannel.records import ChannelStop

logger = logging.getLogger(__name__)

#: (reason, principal) → e-stop event number; the stop channel's `latch_and_stop`
LatchAndStop = Callable[[str, str], int]

SIGNAL_PRINCIPAL = "signal:SIGUSR1"
#: how long after a stop was issued its record waits for the command's reason [s]
REASON_GRACE_S = 0.5
#: how often the reason directory is looked at meanwhile [s]
REASON_POLL_S = 0.02


@dataclass(frozen=True)
class _Issued:
    """A stop the stop thread issued, for the recorder: its reason is still to be found."""

    stop: ChannelStop  # with the reason "<signal> received"
    previous_woke_ns: int  # time.monotonic_ns() when the previous stop's signal woke the thread
    woke_ns: int  # ... and this one's
    issued_ns: int  # time.monotonic_ns() once the stop was issued (or failed)


class SignalStop:
    """Turns each SIGUSR1 into one e-stop on a dedicated thread; `close()` restores the old handler."""

    def __init__(self, latch_and_stop: LatchAndStop, *, on_event: Callable[[ChannelStop], None] | None = None,
                 signum: int = signal.SIGUSR1, reason_directory: Path | None = None,
                 reason_grace_s: float = REASON_GRACE_S) -> None:
        """`reason_directory`: where ``armwarden estop --pid`` writes reasons (None: its default);
        `reason_grace_s`: how long a record waits for a reason after its stop was issued [s]."""
        if not reason_grace_s >= 0:
            raise ValueError(f"reason_grace_s must be >= 0, got {reason_grace_s}")
        self._latch_and_stop = latch_and_stop
        self._reason_directory = reason_directory
        self._reason_grace_ns = round(reason_grace_s * 1e9)
        self._on_event = on_event
        self._signum = signum
        self._raised = threading.Event()
        self._closing = False
        self._closed = threading.Event()  # cuts the recorder's wait for a reason short
        self._issued: queue.SimpleQueue[_Issued | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._recorder: threading.Thread | None = None
        self._started_ns = 0  # time.monotonic_ns() before the handler was installed
        self._previous: Callable[[int, FrameType | None], object] | int | None = None

    def start(self) -> SignalStop:
        """Install the handler (main thread only, as Python requires) and start the threads."""
        if self._thread is not None:
            raise RuntimeError("SignalStop already started")
        self._started_ns = time.monotonic_ns()  # every signal this handler sees was sent after it
        if self._signum == signal.SIGUSR1:  # left by an earlier process with this id: not for our stops
            discard_reasons(directory=self._reason_directory)
        self._recorder = threading.Thread(target=self._record_all, name="armwarden-sigusr1-record", daemon=True)
        self._recorder.start()
        self._thread = threading.Thread(target=self._run, name="armwarden-sigusr1", daemon=True)
        self._thread.start()
        self._previous = signal.signal(self._signum, self._handle)
        return self

    def close(self) -> None:
        """Restore the previous handler and stop the threads; a record still waiting for its
        reason is written at once without it. Idempotent."""
        if self._thread is None or self._closing:
            return
        self._closing = True
        if self._previous is not None:
            signal.signal(self._signum, self._previous)
        self._raised.set()
        self._closed.set()
        self._thread.join(timeout=5.0)
        if self._recorder is not None:
            self._recorder.join(timeout=5.0)

    def __enter__(self) -> SignalStop:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self._raised.set()

    def _run(self) -> None:
        previous_woke_ns = self._started_ns
        try:
            while True:
                self._raised.wait()
                self._raised.clear()
                woke_ns = time.monotonic_ns()  # after clear(): every signal this stop answers was sent before
                if self._closing:
                    return
                stop = self._stop()
                self._issued.put(_Issued(stop, previous_woke_ns, woke_ns, time.monotonic_ns()))
                previous_woke_ns = woke_ns
        finally:
            self._issued.put(None)

    def _stop(self) -> ChannelStop:
        """Issue one stop; the record to write for it, its reason still the default."""
        name = signal.Signals(self._signum).name
        received = time.monotonic()
        try:
            number = self._latch_and_stop(f"{name} received", SIGNAL_PRINCIPAL)
        except Exception as exc:
            logger.critical("%s: the e-stop may NOT have been issued: %s", name, exc, exc_info=True)
            return ChannelStop(SIGNAL_PRINCIPAL, f"{name} received", "signal", None, None, str(exc))
        issued_ms = round((time.monotonic() - received) * 1e3, 4)
        logger.warning("%s: e-stop #%d latched and the robot stopped", name, number)
        return ChannelStop(SIGNAL_PRINCIPAL, f"{name} received", "signal", number, issued_ms, None)

    def _record_all(self) -> None:
        """The recorder: each issued stop, in order, with its reason once found or given up on."""
        while (issued := self._issued.get()) is not None:
            reason = self._reason(issued)
            if reason is not None:
                logger.warning("%s: e-stop #%s reason: %s", signal.Signals(self._signum).name, issued.stop.event, reason)
            self._report(issued.stop if reason is None else dataclasses.replace(issued.stop, reason=reason))

    def _reason(self, issued: _Issued) -> str | None:
        """The reasons ``armwarden estop --pid`` handed over for this stop, waiting for one up to
        the grace after the stop was issued; None when none came."""
        if self._signum != signal.SIGUSR1:
            return None
        deadline_ns = issued.issued_ns + self._reason_grace_ns
        while True:
            try:
                text = take_reasons(directory=self._reason_directory, signalled_from_ns=issued.previous_woke_ns,
                                    signalled_before_ns=issued.woke_ns)
            except Exception:  # take_reasons never raises; the record must be written all the same
                logger.exception("reading the reason of e-stop #%s failed", issued.stop.event)
                return None
            if text:
                return text
            remaining_ns = deadline_ns - time.monotonic_ns()
            if remaining_ns <= 0 or self._closed.wait(min(REASON_POLL_S, remaining_ns / 1e9)):
                return None

    def _report(self, stop: ChannelStop) -> None:
        if self._on_event is None:
            return
        try:
            self._on_event(stop)
        except Exception:
            logger.exception("recording the %s e-stop failed", signal.Signals(self._signum).name)


__all__ = ["REASON_GRACE_S", "SIGNAL_PRINCIPAL", "SignalStop"]
