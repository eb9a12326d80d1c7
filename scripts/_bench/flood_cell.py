#!/usr/bin/env python3
"""The fake FR3 cell (`python -m tests_ros.cell`) with its trajectory goals' ends stamped (used by
`bench.py flood` on the ROS 2 backend; run in .venv-ros with the repository on PYTHONPATH).

Appends one JSON line per event to ``ARMWARDEN_BENCH_CELL_LOG``, stamped on `time.monotonic`
(CLOCK_MONOTONIC, which the sender of an e-stop shares): ``{"kind": "cancel_received", "t"}``
when the action server takes a cancel request (its cancel callback, on the cell's executor), and
``{"kind": "canceled" | "succeed" | "abort", "t"}`` when the goal's loop ends it. The loop moves
the arm every 10 ms (`tests_ros.cell.STATE_PERIOD_S`) and stops moving it when it ends the goal:
"canceled" is when the cell's arm is still — its positions no longer change and its published
velocities are zero from then on.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from typing import Any

from tests_ros import cell


def _stamp_goal_ends(path: str) -> None:
    log = open(path, "a", buffering=1, encoding="utf-8")  # noqa: SIM115 - open for the process's life
    lock = threading.Lock()
    Cell = cell.Cell
    on_cancel, finish = Cell._on_cancel, Cell._finish

    def write(kind: str) -> None:
        stamp = time.monotonic()
        with lock:
            log.write(json.dumps({"kind": kind, "t": stamp}) + "\n")

    def stamped_on_cancel(self: Any, goal_handle: Any) -> Any:
        write("cancel_received")
        return on_cancel(self, goal_handle)

    def stamped_finish(self: Any, goal_handle: Any, outcome: str, code: int, text: str) -> Any:
        write("canceled" if outcome == "cancel" else outcome)
        return finish(self, goal_handle, outcome, code, text)

    Cell._on_cancel, Cell._finish = stamped_on_cancel, stamped_finish  # type: ignore[method-assign]


if __name__ == "__main__":
    _stamp_goal_ends(os.environ["ARMWARDEN_BENCH_CELL_LOG"])
    sys.exit(cell.main(sys.argv[1:]))
