"""Capsules as coal (hpp-fcl) shapes: the independent geometry the envelope's own checks are tested against."""

from __future__ import annotations

import coal
import numpy as np


def coal_capsule(p0: np.ndarray, p1: np.ndarray, radius: float) -> tuple[coal.ShapeBase, coal.Transform3s]:
    """The capsule of `radius` m around the segment p0–p1 (world frame, m) and its placement; a
    sphere when the segment has no length."""
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    if length < 1e-12:
        return coal.Sphere(radius), coal.Transform3s(np.eye(3), p0)
    z = axis / length
    x = np.cross([1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return coal.Capsule(radius, length), coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), (p0 + p1) / 2)
