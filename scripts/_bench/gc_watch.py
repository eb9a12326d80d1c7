#!/usr/bin/env python3
"""Run ``armwarden <args>`` with every long garbage collection recorded (used by `bench.py flood`).

Why: a collection holds the GIL, so it pauses every Python thread of the daemon — the event loop
and the stop channel's thread alike. Each full (generation 2) collection, and any other that
takes more than 2 ms, is appended to the JSON-lines file named by ``ARMWARDEN_BENCH_GC_LOG`` as
``{"gen", "start", "ms", "collected"}`` (start on the monotonic clock, which on Linux every
process on the machine shares), so the benchmark can line pauses up with slow e-stops.

With ``ARMWARDEN_BENCH_ECHO_PORT`` set, a bare thread in the daemon's process answers each
connection on 127.0.0.1:PORT with the byte it read and closes it: the floor of any stop path that
lives in the daemon's interpreter (it needs the GIL and a core like the stop channel's thread,
and does nothing else).

SIGUSR2 (an experiment of the benchmark, not something ArmWarden does): collect once, then
`gc.freeze()` — every object alive at that moment (the robot model, the SDK server, the
compiled schemas) moves to the permanent generation, which later collections skip.
"""

import gc
import json
import os
import signal
import socket
import sys
import threading
import time

from armwarden.cli import main

LONG_S = 0.002


def _watch(log) -> None:
    started: list[float] = []

    def callback(phase: str, info: dict) -> None:
        if phase == "start":
            started[:] = [time.monotonic()]
            return
        if not started:
            return
        begin, end = started.pop(), time.monotonic()
        if info["generation"] == 2 or end - begin > LONG_S:
            log.write(json.dumps({"gen": info["generation"], "start": begin, "ms": (end - begin) * 1e3,
                                  "collected": info["collected"]}) + "\n")

    gc.callbacks.append(callback)

    def freeze(signum: int, frame: object) -> None:
        gc.collect()
        gc.freeze()
        log.write(json.dumps({"frozen": gc.get_freeze_count(), "at": time.monotonic()}) + "\n")

    signal.signal(signal.SIGUSR2, freeze)


def _echo(port: int) -> None:
    listener = socket.create_server(("127.0.0.1", port))

    def serve() -> None:
        while True:
            connection, _ = listener.accept()
            with connection:
                connection.sendall(connection.recv(1) or b"-")

    threading.Thread(target=serve, name="bench-echo", daemon=True).start()


if __name__ == "__main__":
    if os.environ.get("ARMWARDEN_BENCH_ECHO_PORT"):
        _echo(int(os.environ["ARMWARDEN_BENCH_ECHO_PORT"]))
    with open(os.environ["ARMWARDEN_BENCH_GC_LOG"], "a", buffering=1, encoding="utf-8") as gc_log:
        _watch(gc_log)
        sys.exit(main(sys.argv[1:]))
