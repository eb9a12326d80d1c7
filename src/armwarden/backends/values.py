"""The values a backend hands back: how an execution, a gripper action, a snapshot ended, which
controllers it runs. Plain frozen records, so the Guard and the tools read them without the
backend's class."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

ProgressCallback = Callable[[float], None]
#: `ExecutionResult.reason` of an execution a stop preempted before anything moved
PREEMPTED = "stopped before it started"


@dataclass(frozen=True)
class GripperResult:
    success: bool
    width_m: float
    is_grasped: bool
    detail: str = ""


@dataclass(frozen=True)
class CameraImage:
    camera: str
    width: int
    height: int
    png: bytes
    stamp: float


@dataclass(frozen=True)
class ControllerInfo:
    name: str
    type: str
    state: str  # "active" | "inactive"


@dataclass(frozen=True)
class ExecutionResult:
    """How an execution ended: `completed` (reached the goal) or stopped early, with why."""

    completed: bool
    reason: str
    final_positions: np.ndarray
    #: largest deviation [rad] of a measured joint from its commanded trajectory sample while the
    #: trajectory ran; None: the backend does not measure one (a kinematic arm follows exactly)
    max_tracking_error_rad: float | None = None


__all__ = ["PREEMPTED", "CameraImage", "ControllerInfo", "ExecutionResult", "GripperResult",
           "ProgressCallback"]
