"""Conversions from internal dataclasses to the public result models (one place for each)."""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from armwarden.core.state import GripperState, JointState, Wrench
from armwarden.results import (
    EnvelopeModel,
    EStopInfo,
    PlanSummary,
    PoseModel,
    Quaternion,
    Vector3,
    ViolationModel,
    WrenchModel,
)
from armwarden.robot.model import Pose, RobotModel
from armwarden.safety.estop import EStopEvent
from armwarden.safety.violations import Violation

if TYPE_CHECKING:
    from armwarden.policy import Policy
    from armwarden.safety.limits import EnvelopeReport


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


@overload
def estop_info(event: EStopEvent) -> EStopInfo: ...
@overload
def estop_info(event: EStopEvent | None) -> EStopInfo | None: ...
def estop_info(event: EStopEvent | None) -> EStopInfo | None:
    """An e-stop event as the wire model; an event in, an event out (None: no event)."""
    if event is None:
        return None
    return EStopInfo(number=event.number, reason=event.reason, source=event.source, wall_time=iso_utc(event.wall_time))


def robot_state_data(robot: RobotModel, state: JointState, wrench: Wrench | None,
                     gripper: GripperState | None) -> dict[str, Any]:
    """The state as `RobotState`'s JSON data, in its field order. Plain data: it runs on every state
    poll, and the one validation it needs happens where it crosses a boundary — the SDK validates
    a tool's structured result against the tool's output model (`RobotState`), and `Readings.robot_state`
    validates the console's copy."""
    tcp = robot.tcp_pose(state.positions)
    qx, qy, qz, qw = tcp.quaternion_xyzw.tolist()
    forces = None
    if wrench is not None:
        (fx, fy, fz), (tx, ty, tz) = force, torque = wrench.force.tolist(), wrench.torque.tolist()
        if all(map(math.isfinite, force + torque)):  # plain floats: a tenth of NumPy's cost on six numbers
            forces = {"force": {"x": fx, "y": fy, "z": fz}, "torque": {"x": tx, "y": ty, "z": tz}}
    px, py, pz = tcp.position.tolist()
    return {
        "joint_names": list(robot.joint_names),
        "joint_positions": np.asarray(state.positions, dtype=float).tolist(),
        "joint_velocities": np.asarray(state.velocities, dtype=float).tolist(),
        "tcp_pose": {"position": {"x": px, "y": py, "z": pz}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}},
        "frame_id": robot.base_frame,
        "wrench": forces,
        "gripper": None if gripper is None
        else {"width_m": gripper.width_m, "is_grasped": gripper.is_grasped, "moving": gripper.moving},
        "stamp": state.stamp,
    }


def plan_notes(planner_notes: Sequence[str], force_monitoring: bool, require_wrench: bool, dry_run: bool) -> list[str]:
    """The planner's notes plus what the server will (not) do when the plan is executed."""
    notes = list(planner_notes)
    if not force_monitoring:
        notes.append("no wrench estimate: execute_plan will refuse (force.require_wrench is true)" if require_wrench
                     else "no wrench estimate: the contact force limit is NOT enforced")
    if dry_run:
        notes.append("dry run: execute_plan will validate and ask, but nothing will move")
    return notes


def plan_summary(violations: Sequence[Violation], notes: list[str], force_monitoring: bool, *,
                 report: EnvelopeReport | None = None, plan_id: str | None = None,
                 status: str = "rejected", requires_approval: bool = False, duration_s: float = 0.0,
                 expires_at: str | None = None) -> PlanSummary:
    """The summary of a planning call; without a `report` (nothing was planned) a rejection."""
    shown = [violation_model(v) for v in violations]
    if report is None:
        return PlanSummary(
            plan_id=None, status="rejected", violations=shown, requires_approval=False, duration_s=0.0,
            max_joint_velocity_ratio=0.0, max_joint_acceleration_ratio=0.0, max_joint_travel_rad=0.0,
            tcp_path_length_m=0.0, final_tcp_pose=None, force_monitoring=force_monitoring, expires_at=None, notes=notes,
        )
    return PlanSummary(
        plan_id=plan_id,
        status=status,  # type: ignore[arg-type]
        violations=shown,
        requires_approval=requires_approval,
        duration_s=duration_s,
        max_joint_velocity_ratio=report.max_joint_velocity_ratio,
        max_joint_acceleration_ratio=report.max_joint_acceleration_ratio,
        max_joint_travel_rad=report.max_joint_travel_rad,
        tcp_path_length_m=report.tcp_path_length_m,
        final_tcp_pose=None if report.final_tcp_pose is None else pose_model(report.final_tcp_pose),
        force_monitoring=force_monitoring,
        expires_at=expires_at,
        notes=notes,
    )


def envelope_model(policy: Policy, robot: RobotModel, registered_tools: list[str]) -> EnvelopeModel:
    """The limits the server enforces, as `get_safety_envelope` publishes them."""
    p = policy
    ws = p.workspace
    return EnvelopeModel(
        robot=p.robot.name,
        base_frame=p.robot.base_frame,
        tcp_frame=p.robot.tcp_frame,
        joint_names=list(p.robot.joint_names),
        joint_limits={n: p.robot.joint_limits[n].model_dump() for n in p.robot.joint_names},
        workspace_box={"min": list(ws.box.min), "max": list(ws.box.max)},
        keep_out=[{"name": z.name, "min": list(z.min), "max": list(z.max)} for z in ws.keep_out],
        link_padding_m=ws.link_padding_m,
        padding_by_link_m=dict(ws.padding_by_link_m),
        collision_geometry="urdf" if robot.fitted is None else f"fitted ({robot.fitted.robot}, {len(robot.capsules)} capsules)",
        checked_links=sorted({c.link for c in robot.capsules}),
        self_collision=ws.self_collision,
        motion=p.motion.model_dump(),
        force=p.force.model_dump(),
        gripper=None if p.gripper is None else p.gripper.model_dump(),
        controllers_allowlist=list(p.controllers.allowlist),
        cameras=list(p.perception.cameras),
        approval_mode=p.approval.mode,
        dry_run=p.dry_run,
        tools=registered_tools,
    )
