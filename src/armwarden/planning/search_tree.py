"""What one detour search holds while it runs: its two trees and the ends they connect.

A `SearchTree` node carries, beside its configuration and TCP position, what the path from the
tree's root has already used of the per-plan caps (TCP path length, travel per joint), so
`DetourSearch` can keep a node only while the whole path through it can stay within the caps.
Preallocated NumPy arrays: a search adds thousands of nodes and asks for the nearest one each time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SearchEnds", "SearchTree"]


class SearchTree:
    """One search tree: configurations, their TCP positions, and what the path from the root used."""

    def __init__(self, n: int, capacity: int) -> None:
        self.q = np.empty((capacity, n))
        self.tcp = np.empty((capacity, 3))
        self.used_tcp = np.empty(capacity)
        self.used_travel = np.empty((capacity, n))
        self.parent = np.empty(capacity, dtype=np.intp)
        self.root = np.empty(capacity, dtype=np.intp)  # the goal a node of the goal tree leads to; -1: the start
        self.size = 0

    def add(self, q: np.ndarray, tcp: np.ndarray, used_tcp: float, used_travel: np.ndarray, parent: int, root: int) -> int:
        i = self.size
        self.q[i], self.tcp[i], self.used_tcp[i], self.used_travel[i] = q, tcp, used_tcp, used_travel
        self.parent[i], self.root[i] = parent, root
        self.size += 1
        return i

    @property
    def full(self) -> bool:
        return self.size >= len(self.q)

    def nearest(self, q: np.ndarray) -> int:
        d = self.q[: self.size] - q
        return int(np.argmin(np.einsum("ij,ij->i", d, d)))

    def branch(self, i: int) -> list[np.ndarray]:
        """Configurations from node `i` back to the root."""
        out = []
        while i >= 0:
            out.append(self.q[i].copy())
            i = int(self.parent[i])
        return out


@dataclass(frozen=True)
class SearchEnds:
    """The start and the goals (with their approach legs' use of the caps) one search connects."""

    start: np.ndarray
    start_tcp: np.ndarray
    start_rotation: np.ndarray
    goals: np.ndarray  # (G, n)
    goal_tcp: np.ndarray  # (G, 3)
    goal_rotation: np.ndarray  # (G, 3, 3)
    tail_tcp: np.ndarray  # (G,) TCP length of the leg after each goal
    tail_travel: np.ndarray  # (G, n)
