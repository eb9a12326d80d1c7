"""Pydantic result models of the tools: the public contract clients see as `structuredContent`
and `outputSchema`. Field names here are public API; change them only with a version bump.

Units: metres, radians, seconds, newtons; positions in the robot base frame; quaternions xyzw.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class _Result(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Vector3(_Result):
    x: float
    y: float
    z: float


class Quaternion(_Result):
    x: float
    y: float
    z: float
    w: float


class PoseModel(_Result):
    position: Vector3 = Field(description="Position [m] in `frame_id`")
    orientation: Quaternion = Field(description="Orientation as a unit quaternion (x, y, z, w)")


class WrenchModel(_Result):
    force: Vector3 = Field(description="Estimated external force [N]")
    torque: Vector3 = Field(description="Estimated external torque [N·m]")


class GripperModel(_Result):
    width_m: float = Field(description="Finger opening [m]")
    is_grasped: bool
    moving: bool


class RobotState(_Result):
    joint_names: list[str]
    joint_positions: list[float] = Field(description="[rad]")
    joint_velocities: list[float] = Field(description="[rad/s]")
    tcp_pose: PoseModel
    frame_id: str = Field(description="Frame of tcp_pose (the robot base frame)")
    wrench: WrenchModel | None = Field(description="External wrench estimate, or null when the backend has none")
    gripper: GripperModel | None
    stamp: float = Field(description="Monotonic time of the joint state [s]")


class ViolationModel(_Result):
    code: str
    severity: Literal["hard", "soft"]
    detail: str
    time_s: float | None = Field(description="When along the plan [s from start], if it is a moment")
    body: str | None = Field(description="Joint, link or frame concerned")


class PlanSummary(_Result):
    plan_id: str | None = Field(description="Single-use id for execute_plan; null if nothing was planned")
    status: Literal["ok", "needs_approval", "rejected"]
    violations: list[ViolationModel]
    requires_approval: bool = Field(description="Whether execute_plan will ask a human")
    duration_s: float
    max_joint_velocity_ratio: float = Field(description="Peak joint speed as a fraction of its limit")
    max_joint_acceleration_ratio: float = Field(description="Peak joint acceleration as a fraction of its limit")
    max_joint_travel_rad: float
    tcp_path_length_m: float
    final_tcp_pose: PoseModel | None
    force_monitoring: bool = Field(description="Whether the contact force limit will be enforced while moving")
    expires_at: str | None = Field(description="ISO 8601 UTC time after which the plan cannot run")
    notes: list[str]


class ApprovalInfo(_Result):
    required: bool
    operator: str | None = Field(description="Name the human gave, if asked (unverified)")
    via: Literal["not_required", "elicitation", "console", "no_elicitation_client", "dry_run"]


class ExecutionReport(_Result):
    plan_id: str
    status: Literal["succeeded", "dry_run", "aborted"]
    approval: ApprovalInfo
    duration_s: float = Field(description="Time spent moving [s]")
    max_observed_force_n: float | None
    max_external_torques_nm: list[float] | None = Field(
        default=None, description="Per joint, the largest external torque estimated from the motors' torques while it "
        "ran [N·m]; null when the contact was measured by a sensor (or not at all)")
    final_joint_error_rad: float | None = Field(
        default=None, description="Largest distance of a joint from the plan's goal where the arm ended [rad]; "
        "null if the backend reported no end position")
    max_tracking_error_rad: float | None = Field(
        default=None, description="Largest deviation of a measured joint from the commanded trajectory while it "
        "ran [rad]; null if the backend does not measure it (a kinematic simulation follows exactly)")
    detail: str = ""


class MotionStatus(_Result):
    executing: bool
    plan_id: str | None
    progress: float = Field(ge=0.0, le=1.0)
    last_result: ExecutionReport | None


class EStopInfo(_Result):
    number: int
    reason: str
    source: str
    wall_time: str


class SafetyStatus(_Result):
    estopped: bool
    estop_event: EStopInfo | None
    force_violation_latched: bool
    dry_run: bool
    last_violation: ViolationModel | None
    faults: list[str]
    audit_ok: bool = Field(description="Whether the audit log can be written. False: nothing actuates, no e-stop "
                           "can be released, and this answer itself may be unrecorded")
    audit_error: str | None = Field(default=None, description="Why the audit log cannot be written (e.g. its disk "
                                    "is full), or null")


def _audit_error() -> Any:
    """The field a stopping or releasing result sets when its own audit record could not be written."""
    return Field(default=None, description="Set when this call's audit record could not be written (e.g. a full "
                 "disk): what the result says still happened, but the log does not show it")


class EStopResult(_Result):
    estopped: bool
    estop_event: EStopInfo
    audit_error: str | None = _audit_error()


class StopResult(_Result):
    stopped: bool
    detail: str
    audit_error: str | None = _audit_error()


class ResetResult(_Result):
    estopped: bool
    released_event: int | None
    detail: str
    audit_error: str | None = _audit_error()


class GripperResultModel(_Result):
    status: Literal["succeeded", "failed", "dry_run"]
    width_m: float | None
    is_grasped: bool | None
    detail: str


class ActionResult(_Result):
    status: Literal["succeeded", "dry_run"]
    approval: ApprovalInfo
    detail: str


class ControllerModel(_Result):
    name: str
    type: str
    state: str
    switchable: bool = Field(description="Whether the policy lets switch_controllers touch it")


class ControllerList(_Result):
    controllers: list[ControllerModel]


class GraphModel(_Result):
    nodes: list[str]
    topics: list[str]
    services: list[str]
    actions: list[str]


class TransformResult(_Result):
    target_frame: str
    source_frame: str
    pose: PoseModel = Field(description="Pose of source_frame expressed in target_frame")


class AuditTail(_Result):
    records: list[dict]


class CameraResult(_Result):
    camera: str
    width: int
    height: int
    stamp: float


class EnvelopeModel(_Result):
    """The limits the server enforces (from the immutable policy)."""

    robot: str
    base_frame: str
    tcp_frame: str
    joint_names: list[str]
    joint_limits: dict[str, dict[str, float]]
    workspace_box: dict[str, list[float]]
    keep_out: list[dict]
    link_padding_m: float
    padding_by_link_m: dict[str, float] = {}
    collision_geometry: str = "urdf"
    checked_links: list[str]
    self_collision: bool
    motion: dict[str, float | None]
    #: the policy's force section: limits, rate, source (a string) and the joint-torque limits (an object or null)
    force: dict[str, float | bool | str | dict[str, Any] | None]
    gripper: dict[str, float] | None
    controllers_allowlist: list[str]
    cameras: list[str]
    approval_mode: str
    dry_run: bool
    tools: list[str]
