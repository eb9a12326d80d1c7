"""The fake cell's journal and the names the evaluation meets it by (no rclpy: `armwarden eval`
reads these without importing ROS; `armwarden.backends.ros2.fake_cell` writes them)."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import TextIO

#: `python -m` this to run the fake cell as a process of its own
CELL_MODULE = "armwarden.backends.ros2.fake_cell"
#: the first line the standalone cell prints on stdout once its endpoints are up
READY = "fake FR3 cell ready"
#: the journal's name of a gripper goal the cell accepted (a move, a grasp or a homing: the cell
#: cannot tell which tool sent it)
GRIPPER_GOAL = "gripper_goal"


class CellJournal:
    """What the cell accepted, one JSON line each, in the actuation journal's format
    (``{"t": <monotonic s>, "call": ..., "kind": "actuation"|"stop"}``, read by
    `armwarden.evaluation.journal`): a trajectory goal accepted, a trajectory on the topic, a
    gripper goal accepted, a controller switch, an error recovery (actuations), a cancel (a stop).
    Written and flushed as the request arrives, before the cell acts on it, so a goal counts even
    when the cell is killed right after. CLOCK_MONOTONIC is one clock for every process of the
    host, so the stamps compare with the daemon's own journal."""

    def __init__(self, path: Path | None) -> None:
        self._lock = threading.Lock()
        self._file: TextIO | None = None if path is None else path.open("a", encoding="utf-8")

    def write(self, call: str, kind: str = "actuation") -> None:
        if self._file is None:
            return
        line = json.dumps({"t": time.monotonic(), "call": call, "kind": kind}) + "\n"
        with self._lock:
            if self._file is not None:
                self._file.write(line)
                self._file.flush()

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None


__all__ = ["CELL_MODULE", "GRIPPER_GOAL", "READY", "CellJournal"]
