"""The robot description (bundled FR3 + Franka Hand, or a user URDF) and its kinematics."""

from __future__ import annotations

import numpy as np

from armwarden.core.errors import RobotModelError
from armwarden.robot.fitted_bodies import require_limits_within
from armwarden.robot.model import Pose, RobotModel, resolve_description

__all__ = ["Pose", "RobotModel", "build_robot", "resolve_description"]


def build_robot(policy) -> RobotModel:
    """The RobotModel for a policy, its joint limits narrowed to the policy's.

    The policy may be stricter than the description, never looser: a policy limit outside the
    URDF's (the hardware's) is a configuration error.
    """
    robot_cfg = policy.robot
    robot = RobotModel.from_description(
        robot_cfg.description,
        robot_cfg.joint_names,
        robot_cfg.base_frame,
        robot_cfg.tcp_frame,
        check_links=policy.workspace.check_links,
        collision_geometry=robot_cfg.collision_geometry,
    )
    robot.require_tcp_beyond_last_joint()
    lower = np.array(robot_cfg.lower_limits)
    upper = np.array(robot_cfg.upper_limits)
    tolerance = 1e-6
    for name, lo, hi, urdf_lo, urdf_hi in zip(robot_cfg.joint_names, lower, upper, robot.lower, robot.upper, strict=True):
        if lo < urdf_lo - tolerance or hi > urdf_hi + tolerance:
            raise RobotModelError(
                f"policy limits of {name} [{lo}, {hi}] exceed the description's [{urdf_lo}, {urdf_hi}]"
            )
    robot.set_position_limits(lower, upper)
    if robot.fitted is not None:  # its pair proofs hold over the limits it was analysed for only
        require_limits_within(robot.fitted, dict(zip(robot_cfg.joint_names, zip(lower, upper, strict=True), strict=True)))
    return robot
