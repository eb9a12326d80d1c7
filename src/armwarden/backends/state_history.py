"""The joint states a backend published, kept for a moment: what the contact observer integrates.

The observer (`armwarden.safety.contact_observer`) integrates the arm's momentum between samples.
Read at the monitor's poll rate it sees one sample in five of a 1 kHz servo loop and integrates the
torques between them from the two ends alone: on the MuJoCo FR3 at full scaling that error alone
was 5.5 N·m on joint 2 in free motion, 2.1 N·m at every sample. A backend that publishes faster
than the Guard polls keeps its recent samples here, and `Backend.read_joint_states_since` hands the
Guard every one it has not seen.
"""

from __future__ import annotations

import threading
from collections import deque

from armwarden.core.state import JointState

__all__ = ["JointStateHistory"]


class JointStateHistory:
    """The last `capacity` published joint states, oldest first; any thread appends and reads."""

    def __init__(self, capacity: int = 512) -> None:
        if capacity < 1:
            raise ValueError(f"a history holds at least one sample, not {capacity}")
        self._lock = threading.Lock()
        self._states: deque[JointState] = deque(maxlen=capacity)

    def append(self, state: JointState) -> None:
        """Keep `state` (published after every one kept so far: its stamp is not older)."""
        with self._lock:
            self._states.append(state)

    def since(self, stamp: float) -> tuple[JointState, ...]:
        """Every kept state stamped after `stamp`, oldest first (empty: none newer).

        When the reader fell further behind than the history reaches, the first state returned is
        more than one sample after `stamp`: the reader sees the gap in the stamps."""
        with self._lock:
            newer: list[JointState] = []
            for state in reversed(self._states):
                if state.stamp <= stamp:
                    break
                newer.append(state)
        newer.reverse()
        return tuple(newer)

    def since_or_latest(self, stamp: float) -> tuple[JointState, ...]:
        """`since(stamp)`, or the newest kept state alone when none is newer (empty: none kept yet).

        A reader asking again before the next state is kept gets the one it has, not a newer state
        that was never kept: a backend keeps only what the observer can integrate."""
        with self._lock:
            newest = self._states[-1] if self._states else None
        newer = self.since(stamp)
        return newer if newer or newest is None else (newest,)

    def clear(self) -> None:
        with self._lock:
            self._states.clear()
