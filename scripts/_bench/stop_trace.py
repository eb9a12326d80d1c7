#!/usr/bin/env python3
"""Run ``armwarden <args>`` with the stop channel's path stamped (used by `bench.py flood`).

What `gc_watch.py` does (each full or > 2 ms garbage collection logged to
``ARMWARDEN_BENCH_GC_LOG``), plus, for every e-stop the channel serves, one JSON line in
``ARMWARDEN_BENCH_STOP_LOG``: when the connection was accepted, when the request had been read
(``_stop`` entered), when ``latch_and_stop`` was called and returned, when the answer's ``send``
was next ("answering") and when it had been sent (the thread back from ``send`` and ``shutdown``),
each on `time.monotonic` (CLOCK_MONOTONIC, which the sender's stamps share) together with the
channel thread's CPU time and run-queue wait so far (``/proc/<pid>/task/<tid>/schedstat``: time
on a core, time runnable but waiting for one [ns]); and the same for every ``select`` of the
channel's loop around the request (its rounds). Between two stamps, wall time that is neither on
a core nor waiting for one was spent asleep: blocked waiting for the interpreter lock (a
request's bytes were there) or on the backend's locks.

The schedstat file is read with ``pread`` called through `ctypes.PyDLL`, which keeps the
interpreter lock: an ordinary read would release it, and taking it back is exactly the wait being
measured. Stamps cost the channel thread ~10 µs per round.

``ARMWARDEN_BENCH_THREADS`` names a file rewritten every second with the daemon's threads
(``{native id: name}``), so per-thread CPU times read from /proc can be named.

Experiments (not what ArmWarden does): ``ARMWARDEN_BENCH_SWITCH_INTERVAL_S`` replaces the
daemon's `sys.setswitchinterval` value. ``ARMWARDEN_BENCH_ALTERNATE=KIND:A,B`` changes one
setting after every stop's answer, A, B, A, … (so that both variants meet the same load; each
stop's record names its "variant"): ``switch`` the switch interval [s], ``fifo`` the channel
thread's SCHED_FIFO priority (0: the normal scheduler; needs CAP_SYS_NICE), ``defer`` (1: on)
the wake-up of the event loop that a channel stop asks for (to void the plans; they are refused
meanwhile anyway) held back until the answer is out, instead of made inside ``latch_and_stop``
— the wake-up lets the event loop's thread take the interpreter lock before the answer.
"""

from __future__ import annotations

import collections
import ctypes
import json
import os
import sys
import threading
import time
from typing import Any

import gc_watch  # this directory is sys.path[0] when run as a script

import armwarden.daemon.startup
from armwarden.cli import main
from armwarden.stopchannel import external
from armwarden.stopchannel import server as channel_server

#: rounds of the channel's loop kept for the next stop's record (only those near its connection are written)
ROUNDS_KEPT = 256
_LIBC = ctypes.PyDLL(None)  # PyDLL: the interpreter lock is kept during the call
_LIBC.pread.argtypes = (ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_long)
_LIBC.pread.restype = ctypes.c_ssize_t


class ThreadClock:
    """The calling thread's (CPU time, run-queue wait) so far [ns], read without releasing the GIL."""

    def __init__(self) -> None:
        self.native_id = threading.get_native_id()
        self._fd = os.open(f"/proc/self/task/{self.native_id}/schedstat", os.O_RDONLY)
        self._buffer = ctypes.create_string_buffer(128)

    def read(self) -> tuple[int, int]:
        n = _LIBC.pread(self._fd, self._buffer, 127, 0)
        fields = self._buffer.raw[: max(0, n)].split()
        return (int(fields[0]), int(fields[1])) if len(fields) >= 2 else (0, 0)


def _stamp(clock: ThreadClock) -> list[float]:
    cpu, waiting = clock.read()
    return [time.monotonic(), cpu / 1e9, waiting / 1e9]


class Alternation:
    """``ARMWARDEN_BENCH_ALTERNATE`` (module docstring), applied on the channel's thread."""

    def __init__(self, kind: str | None, values: list[float]) -> None:
        self.kind, self.values, self.index = kind, values, 0

    @classmethod
    def from_environment(cls) -> Alternation:
        spec = os.environ.get("ARMWARDEN_BENCH_ALTERNATE")
        if not spec:
            return cls(None, [])
        kind, _, values = spec.partition(":")
        if kind not in ("switch", "fifo", "defer"):
            raise SystemExit(f"ARMWARDEN_BENCH_ALTERNATE: unknown kind {kind!r} (switch, fifo, defer)")
        return cls(kind, [float(v) for v in values.split(",")])

    @property
    def current(self) -> float | None:
        return self.values[self.index % len(self.values)] if self.values else None

    def apply(self) -> None:
        value = self.current
        if value is None:
            return
        if self.kind == "switch":
            sys.setswitchinterval(value)
        elif self.kind == "defer":
            return
        elif value > 0:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(value)))
        else:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    def next(self) -> None:
        self.index += 1
        self.apply()


def _defer_loop_wakeups(alternate: Alternation) -> None:
    """The ``defer`` experiment: while it is on, `ExternalStops` queues the work a stop hands to the
    event loop and hands it over in `record`, which runs once the answer is out."""
    Stops = external.ExternalStops
    on_loop, record = Stops._on_loop, Stops.record
    held: list[Any] = []

    def deferring_on_loop(self: Any, work: Any) -> None:
        if alternate.kind == "defer" and alternate.current:
            held.append(work)
        else:
            on_loop(self, work)

    def releasing_record(self: Any, stop: Any) -> None:
        while held:
            on_loop(self, held.pop(0))
        record(self, stop)

    Stops._on_loop, Stops.record = deferring_on_loop, releasing_record


def _trace_channel(log: Any) -> None:
    """Patch `StopChannel` so that its thread stamps every round and every stop (module docstring)."""
    Channel = channel_server.StopChannel
    serve, stop, send_answer, after_reply = Channel._serve, Channel._stop, Channel._send_answer, Channel._after_reply
    alternate = Alternation.from_environment()
    _defer_loop_wakeups(alternate)

    def traced_serve(self: Any) -> None:
        clock = ThreadClock()
        alternate.apply()
        rounds: collections.deque[tuple[list[float], list[float]]] = collections.deque(maxlen=ROUNDS_KEPT)
        select = self._selector.select

        def traced_select(timeout: float | None = None) -> Any:
            before = _stamp(clock)
            ready = select(timeout)
            rounds.append((before, _stamp(clock)))
            return ready

        latch_and_stop = self._latch_and_stop

        def traced_latch_and_stop(reason: str, principal: str) -> int:
            trace = self._bench_current
            trace["latch"] = _stamp(clock)
            try:
                return latch_and_stop(reason, principal)
            finally:
                trace["issued"] = _stamp(clock)

        self._bench_clock, self._bench_rounds = clock, rounds
        self._selector.select = traced_select
        self._latch_and_stop = traced_latch_and_stop
        serve(self)

    def traced_stop(self: Any, conn: Any, body: bytes) -> None:
        trace = {"read": _stamp(self._bench_clock), "accepted": conn.deadline - self._request_timeout_s,
                 "variant": alternate.current}
        self._bench_current = conn._bench_trace = trace
        stop(self, conn, body)

    def traced_send_answer(self: Any, conn: Any, response: bytes) -> None:
        trace = getattr(conn, "_bench_trace", None)
        if trace is not None:
            trace["answering"] = _stamp(self._bench_clock)  # the answer rendered, its send() next
        send_answer(self, conn, response)

    def traced_after_reply(self: Any, conn: Any) -> None:
        stop = conn.stop
        trace = getattr(conn, "_bench_trace", None) if stop is not None else None
        if stop is not None and trace is not None:
            trace["answered"] = _stamp(self._bench_clock)
            trace["event"] = stop.event
        after_reply(self, conn)
        if trace is not None:
            since = trace["accepted"] - 1.0
            trace["rounds"] = [[*before, *after] for before, after in self._bench_rounds if after[0] >= since]
            log.write(json.dumps(trace) + "\n")
            alternate.next()

    Channel._serve, Channel._stop, Channel._send_answer, Channel._after_reply = (
        traced_serve, traced_stop, traced_send_answer, traced_after_reply)


def _name_threads(path: str) -> None:
    def run() -> None:
        while True:
            names = {str(t.native_id): t.name for t in threading.enumerate() if t.native_id is not None}
            with open(path + ".tmp", "w", encoding="utf-8") as out:
                json.dump(names, out)
            os.replace(path + ".tmp", path)
            time.sleep(1.0)

    threading.Thread(target=run, name="bench-thread-names", daemon=True).start()


if __name__ == "__main__":
    if os.environ.get("ARMWARDEN_BENCH_SWITCH_INTERVAL_S"):
        armwarden.daemon.startup.SWITCH_INTERVAL_S = float(os.environ["ARMWARDEN_BENCH_SWITCH_INTERVAL_S"])
    if os.environ.get("ARMWARDEN_BENCH_ECHO_PORT"):
        gc_watch._echo(int(os.environ["ARMWARDEN_BENCH_ECHO_PORT"]))
    if os.environ.get("ARMWARDEN_BENCH_THREADS"):
        _name_threads(os.environ["ARMWARDEN_BENCH_THREADS"])
    with open(os.environ["ARMWARDEN_BENCH_GC_LOG"], "a", buffering=1, encoding="utf-8") as gc_log, \
            open(os.environ["ARMWARDEN_BENCH_STOP_LOG"], "a", buffering=1, encoding="utf-8") as stop_log:
        gc_watch._watch(gc_log)
        _trace_channel(stop_log)
        sys.exit(main(sys.argv[1:]))
