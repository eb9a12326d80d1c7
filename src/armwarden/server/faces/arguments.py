"""Argument types every face shares: strict finite numbers, bounded names, points and unit
quaternions. The SDK validates them before any tool body runs (no strings for numbers, no
booleans, no NaN/Inf, bounded lengths); the envelope enforces the real limits later."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, Strict

from armwarden.core.errors import RefusalCode, SafetyRefusal

Finite = Annotated[float, Strict(), Field(allow_inf_nan=False)]
Name = Annotated[str, Field(min_length=1, max_length=128)]
StrictBool = Annotated[bool, Strict()]
MAX_WAYPOINTS = 50
POSITION_BOUND_M = 10.0  # sanity bound on any position argument; the envelope enforces the real box
#: sanity bound on any joint target [rad] (a 1e6 rad target made the time parameterisation allocate
#: until the daemon was OOM-killed); the envelope enforces the real joint limits
JOINT_BOUND = 10.0


class Point(BaseModel):
    model_config = ConfigDict(extra="forbid")
    x: Annotated[Finite, Field(ge=-POSITION_BOUND_M, le=POSITION_BOUND_M, description="[m]")]
    y: Annotated[Finite, Field(ge=-POSITION_BOUND_M, le=POSITION_BOUND_M, description="[m]")]
    z: Annotated[Finite, Field(ge=-POSITION_BOUND_M, le=POSITION_BOUND_M, description="[m]")]


class Orientation(BaseModel):
    model_config = ConfigDict(extra="forbid")
    x: Annotated[Finite, Field(ge=-1.0, le=1.0)]
    y: Annotated[Finite, Field(ge=-1.0, le=1.0)]
    z: Annotated[Finite, Field(ge=-1.0, le=1.0)]
    w: Annotated[Finite, Field(ge=-1.0, le=1.0)]


class Waypoint(BaseModel):
    model_config = ConfigDict(extra="forbid")
    position: Point
    orientation: Orientation | None = Field(default=None, description="Unit quaternion xyzw; null keeps the current one")


def unit_rotation(orientation: Orientation | None) -> np.ndarray | None:
    """Rotation matrix of a unit quaternion; refuses (not normalises) a clearly non-unit one."""
    if orientation is None:
        return None
    q = np.array([orientation.x, orientation.y, orientation.z, orientation.w])
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 0.01:
        raise SafetyRefusal(RefusalCode.INVALID, f"orientation must be a unit quaternion (x, y, z, w); its norm is {norm:.4f}")
    import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

    return pin.Quaternion(*(q / norm)[[3, 0, 1, 2]]).toRotationMatrix()
