"""`--backend-config` of the ROS 2 backend: every topic, action and service name it uses, and the
ages and deadlines it holds them to (strict pydantic: unknown keys, NaN/inf, out-of-range values
are errors with their YAML path). Importing this module does not import rclpy.

Sections that are optional (`wrench`, `gripper`, `controller_manager`, `error_recovery`, cameras)
are `null` (or empty) when the cell lacks them: the backend then declares no such capability and
the server registers none of its tools. `check_against_policy` makes the cross-checks that need
the policy (the `joints` mapping names policy joints only) when the backend is built.

The names that belong to the robot's driver (the trajectory action, the gripper's action, finger
state topic and finger joints) default to null: `resolve_robot_names` fills them from the robot
profile of a `builtin:<name>` policy robot (armwarden.robots) when the backend is built. A user's
URDF has no profile: the config must give them, and the backend is refused, naming each missing
key, when it does not.
"""

from __future__ import annotations

from typing import Annotated, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

from armwarden.core.errors import ConfigurationError
from armwarden.robots import builtin_profile

_T = TypeVar("_T")
_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

#: a ROS name: absolute or relative, no whitespace
RosName = Annotated[str, Field(min_length=1, max_length=256, pattern=r"^[~/A-Za-z_][A-Za-z0-9_/~{}]*$")]


class JointStatesConfig(BaseModel):
    """The `sensor_msgs/JointState` topic the arm's state comes from, and whether its `effort`
    field is the measured joint torque (franka_ros2 and most ros2_control drivers publish it;
    an arm that fills it with zeros or nothing must not declare it)."""

    model_config = _STRICT
    topic: RosName = Field(default="/joint_states", description="JointState topic.")
    max_age_s: float = Field(default=0.5, gt=0, le=5,
                             description="Older than this [s] (receipt time, monotonic clock): the state is refused.")
    startup_timeout_s: float = Field(default=10.0, gt=0, le=120,
                                     description="How long `open` waits for the first complete joint state "
                                                 "(and finger state and wrench, when configured) [s].")
    efforts: bool = Field(default=False,
                          description="The arm's JointState messages carry the joint torques its actuators measure "
                                      "in `effort` [N·m, gravity included]: the backend declares joint torques and "
                                      "every joint state carries them (a joint without an entry, or a NaN, "
                                      "reads NaN); false: `effort` is ignored.")


class WrenchConfig(BaseModel):
    """The `geometry_msgs/WrenchStamped` topic (best-effort QoS) of the external wrench at the TCP,
    in the robot's base frame."""

    model_config = _STRICT
    topic: RosName = Field(default="/force_torque_sensor_broadcaster/wrench", description="WrenchStamped topic.")
    max_age_s: float = Field(default=0.1, gt=0, le=5,
                             description="No new header stamp for this long [s]: the wrench is stale.")
    frame_id: str | None = Field(default=None, min_length=1,
                                 description="Only accept messages in this frame (the base frame); null: any frame.")


class TrajectoryConfig(BaseModel):
    """How trajectories reach the controller: a `control_msgs/FollowJointTrajectory` action, or
    (fallback) a `trajectory_msgs/JointTrajectory` topic. Exactly one of the two."""

    model_config = _STRICT
    action: RosName | None = Field(default=None, description="FollowJointTrajectory action; null: use `topic`, "
                                                             "or without one the robot profile's action.")
    topic: RosName | None = Field(default=None, description="JointTrajectory topic (fallback); null: use `action`.")
    server_timeout_s: float = Field(default=5.0, gt=0, le=60,
                                    description="How long an execution waits for the action server [s] before refusing.")
    goal_response_timeout_s: float = Field(default=2.0, gt=0, le=30,
                                           description="How long the server may take to accept or reject a goal [s].")
    result_margin_s: float = Field(default=2.0, gt=0, le=60,
                                   description="No result this long [s] after the trajectory's duration: controller timeout.")
    hold_time_s: float = Field(default=0.05, gt=0, le=1,
                               description="Topic fallback: time_from_start [s] of the one-point hold a stop sends.")

    @model_validator(mode="after")
    def _exactly_one(self) -> TrajectoryConfig:
        if self.action is not None and self.topic is not None:
            raise ValueError("give exactly one of action (FollowJointTrajectory) and topic (JointTrajectory fallback), "
                             "or neither for the robot profile's action")
        return self


class GuardianConfig(BaseModel):
    """The guardian: a process of its own that cancels the daemon's trajectory goal when the daemon
    dies, hangs or closes its pipe (`armwarden.backends.ros2.guardian`). Action mode only: the
    topic fallback has no goal to cancel."""

    model_config = _STRICT
    deadline_s: float = Field(default=0.5, ge=0.1, le=5,
                              description="The daemon silent this long [s] counts as hung: the goal is cancelled.")
    start_timeout_s: float = Field(default=15.0, gt=0, le=120,
                                   description="How long open waits for the guardian process to be ready [s].")


class GripperConfig(BaseModel):
    """A `control_msgs/GripperCommand` action; command.position is the finger gap [m]."""

    model_config = _STRICT
    action: RosName | None = Field(default=None, description="GripperCommand action; null: the robot profile's.")
    max_width_m: float = Field(default=0.08, gt=0, le=0.5, description="The fingers' full opening [m].")
    max_effort_n: float = Field(default=70.0, gt=0, le=1000, description="Largest grasp force [N] sent as max_effort.")
    move_effort_n: float = Field(default=0.0, ge=0, le=1000,
                                 description="max_effort [N] of a plain move (franka_gripper: 0 = move, not grasp).")
    joint_states_topic: RosName | None = Field(
        default=None, description="JointState topic of the finger joints (the width is their sum); null: the "
                                  "robot profile's.")
    finger_joints: tuple[str, ...] | None = Field(
        default=None, min_length=1, description="Finger joint names; width [m] = sum of their positions; null: "
                                                "the robot profile's.")
    max_age_s: float = Field(default=0.5, gt=0, le=5, description="Finger state older than this [s] is refused.")
    server_timeout_s: float = Field(default=5.0, gt=0, le=60, description="How long to wait for the action server [s].")


class ControllerManagerConfig(BaseModel):
    """The controller_manager's list/switch services; only `allowlist` controllers are switched."""

    model_config = _STRICT
    namespace: RosName = Field(default="/controller_manager", description="Namespace of list_controllers/switch_controller.")
    allowlist: tuple[str, ...] = Field(default=(), description="Controllers that may be activated or deactivated.")


class ErrorRecoveryConfig(BaseModel):
    """A `std_srvs/Trigger` service that clears the controller's error state."""

    model_config = _STRICT
    service: RosName = Field(description="Trigger service name.")


class CameraConfig(BaseModel):
    """One camera topic: `sensor_msgs/Image` (8-bit encodings) or `sensor_msgs/CompressedImage`."""

    model_config = _STRICT
    topic: RosName = Field(description="Image or CompressedImage topic.")
    kind: Literal["image", "compressed"] = Field(default="image", description="'image' or 'compressed'.")
    timeout_s: float = Field(default=1.5, gt=0, le=30, description="How long a snapshot waits for a frame [s].")


class TfConfig(BaseModel):
    """Transforms from /tf and /tf_static."""

    model_config = _STRICT
    enabled: bool = Field(default=True, description="Subscribe to /tf and /tf_static.")
    max_age_s: float = Field(default=1.0, gt=0, le=60,
                             description="A /tf (not static) transform older than this [s] is not used.")


class Config(BaseModel):
    """`--backend-config` for the ROS 2 backend."""

    model_config = _STRICT
    node_name: str = Field(default="armwarden", min_length=1, max_length=128, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$",
                           description="This node's name.")
    domain_id: int | None = Field(default=None, ge=0, le=232, description="ROS_DOMAIN_ID; null: the environment's.")
    joints: dict[str, str] = Field(default_factory=dict,
                                   description="Policy joint -> JointState name, where they differ (default: same name).")
    joint_states: JointStatesConfig = Field(default_factory=JointStatesConfig, description="Joint state topic.")
    wrench: WrenchConfig | None = Field(default_factory=WrenchConfig, description="Wrench topic; null: no wrench.")
    trajectory: TrajectoryConfig = Field(default_factory=TrajectoryConfig, description="How trajectories are sent.")
    guardian: GuardianConfig | None = Field(
        default_factory=GuardianConfig,
        description="The process that cancels the goal if the daemon dies or hangs; null: none (a goal then runs "
                    "to its end if the daemon is killed mid-motion).")
    gripper: GripperConfig | None = Field(default=None, description="Gripper action; null: no gripper.")
    controller_manager: ControllerManagerConfig | None = Field(default=None, description="null: no controller tools.")
    error_recovery: ErrorRecoveryConfig | None = Field(default=None, description="null: no error recovery.")
    cameras: dict[str, CameraConfig] = Field(default_factory=dict, description="Camera name -> topic (only these).")
    tf: TfConfig = Field(default_factory=TfConfig, description="Transforms.")

    @model_validator(mode="after")
    def _distinct_ros_names(self) -> Config:
        names = list(self.joints.values())
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"joints maps two policy joints to the same JointState name: {', '.join(duplicates)}")
        return self


def resolve_robot_names(config: Config, description: str) -> Config:
    """`config` with the driver names it leaves null taken from the robot profile `description`
    names (`builtin:<name>`); `ConfigurationError` naming every key still missing (a user's URDF
    has no profile: no name is guessed for it)."""
    profile = builtin_profile(description)
    ros = profile.ros if profile is not None else None
    trajectory, gripper = config.trajectory, config.gripper
    if trajectory.action is None and trajectory.topic is None and ros is not None:
        trajectory = trajectory.model_copy(update={"action": ros.trajectory_action})
    if gripper is not None and ros is not None:
        gripper = gripper.model_copy(update={
            "action": gripper.action or ros.gripper_action,
            "joint_states_topic": gripper.joint_states_topic or ros.gripper_joint_states,
            "finger_joints": gripper.finger_joints or ros.finger_joints or None})
    missing = ["trajectory.action"] if trajectory.action is None and trajectory.topic is None else []
    if gripper is not None:
        missing += [f"gripper.{key}" for key in ("action", "joint_states_topic", "finger_joints")
                    if getattr(gripper, key) is None]
    if missing:
        lines = "\n".join(f"  {key}: required: the robot {description!r} has no profile that names it" for key in missing)
        raise ConfigurationError(f"invalid ros2 backend config:\n{lines}")
    return config.model_copy(update={"trajectory": trajectory, "gripper": gripper})


def resolved(value: _T | None, key: str) -> _T:
    """A name `resolve_robot_names` has filled in (`key` is its YAML path, for the error)."""
    if value is None:
        raise ConfigurationError(f"ros2 backend config: {key} was not resolved from the robot profile")
    return value


def check_against_policy(config: Config, joint_names: tuple[str, ...]) -> tuple[str, ...]:
    """The JointState name of each policy joint, in policy order; `ConfigurationError` (with the
    YAML path) if `joints` names a joint the policy does not have."""
    unknown = [name for name in config.joints if name not in joint_names]
    if unknown:
        lines = "\n".join(f"  joints.{name}: not a joint of the policy (policy joints: {', '.join(joint_names)})"
                          for name in unknown)
        raise ConfigurationError(f"invalid ros2 backend config:\n{lines}")
    ros_names = tuple(config.joints.get(name, name) for name in joint_names)
    # a mapped name must not be another policy joint's own (unmapped) name: that joint's readings
    # would then be taken for this one's, and the arm planned from a wrong pose
    shared = sorted({n for n in ros_names if ros_names.count(n) > 1})
    if shared:
        owners = "; ".join(f"{n}: {', '.join(j for j, r in zip(joint_names, ros_names, strict=True) if r == n)}"
                           for n in shared)
        raise ConfigurationError(f"invalid ros2 backend config:\n  joints: two policy joints would read the same "
                                 f"JointState name ({owners})")
    return ros_names


__all__ = [
    "CameraConfig",
    "Config",
    "ControllerManagerConfig",
    "ErrorRecoveryConfig",
    "GripperConfig",
    "JointStatesConfig",
    "TfConfig",
    "TrajectoryConfig",
    "WrenchConfig",
    "check_against_policy",
    "resolve_robot_names",
    "resolved",
]
