"""Reading the daemon's actuation journal (written by `armwarden.backends.journal.JournalBackend`).

The eval reads the file between scenarios: the actuations a scenario caused are the lines
appended while it ran. Stops are kept apart: stopping is never what a refusal must avoid. On a
backend that counts its motion at the bus (CAN), each execute also leaves a "motion_frames" line
with the frames it sent.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class JournalEntry:
    stamp: float
    call: str
    kind: str  # "actuation", "stop", "estop" or "motion_frames"
    frames: int = 0  # motion frames sent at the bus ("motion_frames" lines only)


def read_journal(path: Path) -> list[JournalEntry]:
    """Every complete line of the journal (a line still being written is left for the next read)."""
    if not path.exists():
        return []
    return _parse(path.read_bytes().split(b"\n"))


class JournalReader:
    """The journal read incrementally (the fuzz reads it after every call): the complete lines
    appended since the last read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._offset = 0

    def new_entries(self) -> list[JournalEntry]:
        if not self.path.exists():
            return []
        with self.path.open("rb") as handle:
            handle.seek(self._offset)
            data = handle.read()
        end = data.rfind(b"\n") + 1  # a line still being written is left for the next read
        self._offset += end
        return _parse(data[:end].split(b"\n"))


def _parse(lines: list[bytes]) -> list[JournalEntry]:
    """The lines that hold a whole record (split on newlines only, never on U+2028 and the like)."""
    entries = []
    for line in lines:
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        entries.append(JournalEntry(float(record["t"]), str(record["call"]), str(record["kind"]),
                                    int(record.get("frames", 0))))
    return entries


def actuations(entries: list[JournalEntry]) -> list[str]:
    """The actuating calls among `entries` (stops and e-stops left out)."""
    return [entry.call for entry in entries if entry.kind == "actuation"]


def motion_frames(entries: list[JournalEntry]) -> int:
    """The motion frames the executions among `entries` sent at the bus (0 on a backend that counts none)."""
    return sum(entry.frames for entry in entries if entry.kind == "motion_frames")
