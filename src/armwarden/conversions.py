"""Conversions from internal dataclasses to the public result models (one place for each)."""

from __future__ import annotations

import datetime as _dt

import numpy as np

from armwarden.backends.base import Wrench
from armwarden.results import EStopInfo, PoseModel, Quaternion, Vector3, ViolationModel, WrenchModel
from armwarden.robot.model import Pose
from armwarden.safety.estop import EStopEvent
from armwarden.safety.violations import Violation


def vector(values) -> Vector3:
    x, y, z = (float(v) for v in values)
    return Vector3(x=x, y=y, z=z)


def pose_model(pose: Pose) -> PoseModel:
    qx, qy, qz, qw = (float(v) for v in pose.quaternion_xyzw)
    return PoseModel(position=vector(pose.position), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))


def violation_model(violation: Violation) -> ViolationModel:
    return ViolationModel(
        code=violation.code.value,
        severity=violation.severity.value,
        detail=violation.detail,
        time_s=violation.time_s,
        body=violation.body,
    )


def wrench_model(wrench: Wrench | None) -> WrenchModel | None:
    if wrench is None or not (np.all(np.isfinite(wrench.force)) and np.all(np.isfinite(wrench.torque))):
        return None
    return WrenchModel(force=vector(wrench.force), torque=vector(wrench.torque))


def iso_utc(wall_time: float) -> str:
    """ISO 8601 UTC with milliseconds and a `Z`, the one time format of every result."""
    stamp = _dt.datetime.fromtimestamp(wall_time, tz=_dt.timezone.utc).isoformat(timespec="milliseconds")
    return stamp.replace("+00:00", "Z")


def estop_info(event: EStopEvent | None) -> EStopInfo | None:
    if event is None:
        return None
    return EStopInfo(number=event.number, reason=event.reason, source=event.source, wall_time=iso_utc(event.wall_time))
