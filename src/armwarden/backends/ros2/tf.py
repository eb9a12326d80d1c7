"""A small transform buffer fed from /tf and /tf_static (tf2_ros is not on PyPI).

It keeps the latest transform per child frame (parent, translation, rotation, receipt time) and
answers "where is `source` in `target`" by composing each frame's parent chain up to a common
root. No interpolation in time: a /tf transform older than `max_age_s` is refused (a static one
never ages), so a stopped broadcaster gives an error, not an old pose.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from armwarden.backends.parts import FrameTree
from armwarden.core.errors import BackendError
from armwarden.core.state import Transform

#: parent chains longer than this are refused (a cycle, or a malformed tree)
MAX_DEPTH = 64


def _rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w, w ≥ 0) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    q = np.array([x, y, z, w])
    return q / np.linalg.norm(q)


@dataclass(frozen=True)
class FrameTransform:
    """Pose of `child` in `parent`: a 4×4 homogeneous matrix; `stamp` = receipt (monotonic) [s]."""

    parent: str
    child: str
    matrix: np.ndarray
    stamp: float
    static: bool


@dataclass(frozen=True)
class TransformReading:
    """Pose of `source_frame` in `target_frame`: translation [m], rotation quaternion (x, y, z, w)."""

    target_frame: str
    source_frame: str
    translation: np.ndarray
    rotation_xyzw: np.ndarray


class TransformBuffer:
    """Latest transform per child frame; `accept` from the executor thread, `lookup` from anywhere."""

    def __init__(self, max_age_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.max_age_s = max_age_s
        self._clock = clock
        self._lock = threading.Lock()
        self._by_child: dict[str, FrameTransform] = {}

    def accept(self, msg, *, static: bool) -> None:
        """Take a tf2_msgs/TFMessage (non-finite or zero-norm rotations are skipped)."""
        now = self._clock()
        for t in msg.transforms:
            tr, ro = t.transform.translation, t.transform.rotation
            translation = np.array([tr.x, tr.y, tr.z], dtype=float)
            q = np.array([ro.x, ro.y, ro.z, ro.w], dtype=float)
            if not (np.all(np.isfinite(translation)) and np.all(np.isfinite(q)) and np.linalg.norm(q) > 1e-9):
                continue
            matrix = np.eye(4)
            matrix[:3, :3], matrix[:3, 3] = _rotation(q), translation
            parent, child = t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/")
            with self._lock:
                self._by_child[child] = FrameTransform(parent, child, matrix, now, static)

    def frames(self) -> tuple[str, ...]:
        with self._lock:
            known = set(self._by_child) | {t.parent for t in self._by_child.values()}
        return tuple(sorted(known))

    def _chain(self, frame: str, now: float) -> list[FrameTransform]:
        """Transforms from `frame` up to its root (child first)."""
        chain: list[FrameTransform] = []
        while frame in self._by_child:
            link = self._by_child[frame]
            if not link.static and now - link.stamp > self.max_age_s:
                raise BackendError(f"the transform {link.parent} -> {link.child} is {now - link.stamp:.2f} s old "
                                   f"(limit {self.max_age_s:g} s)")
            chain.append(link)
            frame = link.parent
            if len(chain) > MAX_DEPTH:
                raise BackendError(f"the frame tree above {chain[0].child} is deeper than {MAX_DEPTH} (a cycle?)")
        return chain

    def lookup(self, target_frame: str, source_frame: str) -> TransformReading:
        """Pose of `source_frame` in `target_frame`; `BackendError` naming what is missing."""
        target, source = target_frame.lstrip("/"), source_frame.lstrip("/")
        with self._lock:
            now = self._clock()
            known = set(self._by_child) | {t.parent for t in self._by_child.values()}
            for name in (target, source):
                if name not in known:
                    shown = ", ".join(sorted(known)[:40]) or "none yet"
                    raise BackendError(f"unknown frame {name[:80]!r}; frames on /tf and /tf_static: {shown}")
            up_source, up_target = self._chain(source, now), self._chain(target, now)
        root_source = up_source[-1].parent if up_source else source
        root_target = up_target[-1].parent if up_target else target
        if root_source != root_target:
            raise BackendError(f"frames {target!r} and {source!r} are not connected (roots {root_target!r}, {root_source!r})")
        in_root_source, in_root_target = np.eye(4), np.eye(4)
        for link in up_source:
            in_root_source = link.matrix @ in_root_source
        for link in up_target:
            in_root_target = link.matrix @ in_root_target
        relative = np.linalg.inv(in_root_target) @ in_root_source
        return TransformReading(target, source, relative[:3, 3].copy(), _quaternion(relative[:3, :3]))


class TfFrames(FrameTree):
    """The frame tree part: lookups in `buffer`, stamped when they are read (the buffer has
    already refused a transform older than its `max_age_s`)."""

    def __init__(self, buffer: TransformBuffer) -> None:
        self.buffer = buffer

    async def lookup(self, target_frame: str, source_frame: str) -> Transform:
        reading = self.buffer.lookup(target_frame, source_frame)
        return Transform(reading.translation, reading.rotation_xyzw, time.monotonic())


__all__ = ["FrameTransform", "TfFrames", "TransformBuffer", "TransformReading"]
