"""Start-up checks that need more than the policy file: the robot description and the envelope.

`load_runtime_model` loads the policy's robot description with Pinocchio, builds the envelope
and checks the home configuration against it, turning every mismatch into a `PolicyError` with
the YAML path to fix. Both `armwarden check-policy` and `armwarden serve` run it, so a policy
that passes `check-policy` starts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armwarden.core.errors import PolicyError, RobotModelError
from armwarden.core.trajectory import JointTrajectory
from armwarden.planning.around import DetourPlanner
from armwarden.planning.planners import Planner, PlannerSettings
from armwarden.policy import Policy
from armwarden.robot import RobotModel, build_robot
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import EnvelopeLimits


@dataclass(frozen=True)
class RuntimeModel:
    """The policy with the kinematic objects built from it (one set per process)."""

    policy: Policy
    robot: RobotModel
    envelope: Envelope
    planner: Planner
    detours: DetourPlanner | None = None  # plans around a blocked straight line (None: straight lines only)


def load_runtime_model(policy: Policy, source: str = "<policy>") -> RuntimeModel:
    try:
        robot = build_robot(policy)
        envelope = Envelope(robot, EnvelopeLimits.from_policy(policy))
    except RobotModelError as exc:
        raise PolicyError(source, [(_path_for(str(exc)), str(exc))]) from exc
    home = np.array(policy.robot.home_joint_positions, dtype=float)
    report = envelope.check(JointTrajectory(robot.joint_names, np.array([0.0, 1.0]), np.vstack([home, home])))
    problems = [
        ("robot.home_joint_positions", f"the home configuration violates the envelope: {v.code.value}: {v.detail}")
        for v in report.hard
    ]
    if problems:
        raise PolicyError(source, problems)
    planner = Planner(robot, PlannerSettings.from_policy(policy))
    return RuntimeModel(policy, robot, envelope, planner, DetourPlanner(planner, envelope, policy.motion.planning_time_s))


def _path_for(message: str) -> str:
    """Best YAML path for a robot-model error message."""
    if "check_links" in message:
        return "workspace.check_links"
    if "padding_by_link_m" in message:
        return "workspace.padding_by_link_m"
    if "collision geometry" in message or "pair analysis" in message:
        return "robot.collision_geometry"
    if message.startswith("base frame"):  # before "joint": these messages list or name joints too
        return "robot.base_frame"
    if message.startswith("TCP frame"):
        return "robot.tcp_frame"
    if "joint" in message and "limits" in message:
        return "robot.joint_limits"
    if "joint" in message:
        return "robot.joint_names"
    if "frame" in message:
        return "robot.tcp_frame"
    return "robot.description"
