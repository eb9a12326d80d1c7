"""The robots ArmWarden ships, one folder each (`robots/<name>/`): its description, fitted
collision geometry, bundled policies and the profile that indexes them (`profile.yaml`).

`builtin:<name>` in a policy (`robot.description`, `robot.collision_geometry`) names such a
folder; `bundled_policy` finds a bundled policy by name. Adding a robot is a folder here
(docs/add-a-robot.md); nothing in the code names one.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from armwarden.core.errors import RobotModelError

BUILTIN_PREFIX = "builtin:"
PROFILE_FILE = "profile.yaml"
#: a file inside the robot's folder (no path separators: a profile cannot point outside it)
FileName = Annotated[str, Field(min_length=1, max_length=128, pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")]
#: a ROS name as a robot's driver publishes it (absolute, no whitespace)
RosName = Annotated[str, Field(min_length=2, max_length=256, pattern=r"^/[A-Za-z_][A-Za-z0-9_/]*$")]
#: a name in the robot's description (joint, link, frame) or a controller's name
ItemName = Annotated[str, Field(min_length=1, max_length=128, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]
Vector3 = tuple[float, float, float]
_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ControllerEntry(BaseModel):
    """A controller the robot's ros2_control set-up loads."""

    model_config = _STRICT
    name: ItemName
    type: Annotated[str, Field(min_length=1, max_length=256)] = Field(description="its plugin, `package/Class`")
    state: Literal["active", "inactive"] = Field(description="its state when the cell comes up")


class ControllersProfile(BaseModel):
    """The robot's ros2_control controllers, as a simulated cell reports and switches them."""

    model_config = _STRICT
    trajectory: ItemName = Field(description="the controller that executes trajectories; arm motion is "
                                             "refused while it is inactive")
    arm_command_types: tuple[Annotated[str, Field(min_length=1)], ...] = Field(
        min_length=1, description="type prefixes of the controllers that command the arm joints: at most one "
                                  "of them may be active (ros2_control's claims)")
    loaded: tuple[ControllerEntry, ...] = Field(min_length=1, description="every controller loaded, in order")

    @model_validator(mode="after")
    def _trajectory_loaded(self) -> ControllersProfile:
        names = [entry.name for entry in self.loaded]
        if self.trajectory not in names:
            raise ValueError(f"the trajectory controller {self.trajectory!r} is not loaded ({', '.join(names)})")
        if len(set(names)) != len(names):
            raise ValueError(f"a controller is loaded twice: {', '.join(names)}")
        return self


class RosProfile(BaseModel):
    """The ROS 2 names of the robot's driver: the ROS 2 backend's defaults, the fake's reported graph."""

    model_config = _STRICT
    trajectory_action: RosName = Field(description="the arm's FollowJointTrajectory action")
    gripper_action: RosName | None = Field(default=None, description="GripperCommand action; null: no gripper")
    gripper_joint_states: RosName | None = Field(default=None, description="JointState topic of the fingers")
    finger_joints: tuple[ItemName, ...] = Field(default=(), description="finger joints; width [m] = sum of "
                                                                          "their positions")
    wrench_topic: RosName | None = Field(default=None, description="WrenchStamped topic of the external "
                                                                   "wrench in the base frame; null: none")
    nodes: tuple[RosName, ...] = Field(default=(), description="the driver's own nodes")
    services: tuple[RosName, ...] = Field(default=(), description="the driver's own services")
    actions: tuple[RosName, ...] = Field(default=(), description="the driver's actions besides the trajectory one")

    @model_validator(mode="after")
    def _gripper_complete(self) -> RosProfile:
        parts = (self.gripper_action is not None, self.gripper_joint_states is not None, bool(self.finger_joints))
        if any(parts) and not all(parts):
            raise ValueError("a gripper needs gripper_action, gripper_joint_states and finger_joints together")
        return self


class CameraMount(BaseModel):
    """A simulated camera. World cameras (`body` null) sit in the policy's base frame, body cameras
    in that body's frame; the camera looks from `position_m` at `target_m` [m]."""

    model_config = _STRICT
    name: ItemName
    position_m: Vector3
    target_m: Vector3
    body: ItemName | None = Field(default=None, description="the link it is mounted on; null: the world")
    up: Vector3 = Field(default=(0.0, 0.0, 1.0), description="the image's up direction, same frame")
    fovy_deg: float = Field(default=45.0, gt=0, lt=180, description="vertical field of view [deg]")


class ActuatorEntry(BaseModel):
    """One arm joint's drive as the MuJoCo backend simulates it."""

    model_config = _STRICT
    armature_kg_m2: float = Field(gt=0, description="the drive's rotor inertia reflected through its gearbox "
                                                    "[kg·m²], added to the joint's inertia")


class RobotProfile(BaseModel):
    """One robot's `profile.yaml`."""

    model_config = _STRICT

    format: Literal["armwarden-robot-profile/1"]
    name: Annotated[str, Field(pattern=r"^[a-z0-9_]+$")]
    title: str
    description: FileName = Field(description="the URDF")
    collision_geometry: FileName | None = Field(default=None, description="fitted collision geometry, if any")
    policies: dict[Annotated[str, Field(pattern=r"^[a-z0-9_]+$")], FileName] = Field(
        min_length=1, description="bundled policies by name; the first is the robot's default")
    base_frame: ItemName | None = Field(default=None, description="the frame positions are given in (as the "
                                                                   "bundled policies say); null: none given")
    tcp_frame: ItemName | None = Field(default=None, description="the tool centre point's frame; null: none given")
    ready_joint_positions: dict[ItemName, float] | None = Field(
        default=None, min_length=1, description="the arm's joints in order and their ready pose [rad]; null: none given")
    controllers: ControllersProfile | None = Field(default=None, description="null: the backends' generic set")
    ros: RosProfile | None = Field(default=None, description="null: the ROS 2 names must be configured")
    cameras: tuple[CameraMount, ...] | None = Field(default=None, description="simulated cameras; null: none")
    actuators: dict[ItemName, ActuatorEntry] | None = Field(
        default=None, min_length=1, description="each arm joint's drive, as the MuJoCo backend simulates it; null: "
                                                "its generic rule by drive size")

    @model_validator(mode="after")
    def _actuators_are_the_arms(self) -> RobotProfile:
        """Every arm joint has its actuator and nothing else does (the arm: `ready_joint_positions`;
        without it the MuJoCo backend checks them against the policy's joints)."""
        if self.actuators is None or self.ready_joint_positions is None:
            return self
        arm = list(self.ready_joint_positions)
        strangers = [joint for joint in self.actuators if joint not in arm]
        if strangers:
            raise ValueError(f"actuators name joints that are not the arm's: {', '.join(strangers)} "
                             f"(the arm: {', '.join(arm)})")
        missing = [joint for joint in arm if joint not in self.actuators]
        if missing:
            raise ValueError(f"actuators lack arm joints: {', '.join(missing)}")
        return self

    def file(self, name: str) -> Path:
        """The path of a file of this profile's folder."""
        return _robots_dir() / self.name / name


def _robots_dir() -> Path:
    return Path(str(resources.files("armwarden") / "robots"))


@functools.cache
def builtin_robots() -> tuple[str, ...]:
    """The names of the robots shipped (each folder with a profile), sorted."""
    return tuple(sorted(path.parent.name for path in _robots_dir().glob(f"*/{PROFILE_FILE}")))


@functools.cache
def load_profile(name: str) -> RobotProfile:
    """The profile of the shipped robot `name`; RobotModelError for an unknown or invalid one."""
    if name not in builtin_robots():
        raise RobotModelError(f"unknown built-in robot {name!r}; available: "
                              + ", ".join(BUILTIN_PREFIX + robot for robot in builtin_robots()))
    path = _robots_dir() / name / PROFILE_FILE
    try:
        profile = RobotProfile.model_validate(yaml.safe_load(path.read_text(encoding="utf-8")))
    except (OSError, yaml.YAMLError, ValidationError) as exc:
        raise RobotModelError(f"the robot profile {path} is invalid: {exc}") from exc
    if profile.name != name:
        raise RobotModelError(f"the robot profile {path} names the robot {profile.name!r}, its folder {name!r}")
    return profile


def bundled_policies() -> dict[str, Path]:
    """Every bundled policy by name, across the shipped robots."""
    found: dict[str, Path] = {}
    for robot in builtin_robots():
        profile = load_profile(robot)
        found |= {policy: profile.file(file) for policy, file in profile.policies.items()}
    return found


def builtin_profile(description: str) -> RobotProfile | None:
    """The profile a policy's `robot.description` names (`builtin:<name>`); None for a user's URDF."""
    return load_profile(description[len(BUILTIN_PREFIX):]) if description.startswith(BUILTIN_PREFIX) else None


__all__ = ["BUILTIN_PREFIX", "ActuatorEntry", "CameraMount", "ControllerEntry", "ControllersProfile", "RobotProfile", "RosProfile",
           "builtin_profile", "builtin_robots", "bundled_policies",
           "load_profile"]
