"""The ROS 2 backend: any ros2_control arm through standard interfaces, over real rclpy.

One job per module: `config` (the strict `--backend-config`; no rclpy), `bridge` (a private rclpy
context, node and executor thread; rclpy futures awaited from asyncio), `state` (thread-safe
caches of joint states and wrench with their receipt times), `images` (sensor_msgs images to
PNG), `tf` (a small transform buffer and the frame tree part), `runs` (the trajectory and hold
messages, the records of goals in flight and of stops), `endpoints` (the node's long-lived rclpy
entities), `arm` (trajectory goals, the topic fallback and their stops), and the cell's parts
(`armwarden.backends.parts`): `gripper` (GripperCommand), `controllers` (controller_manager and
recovery calls), `cameras` (snapshots), `graph` (the node's view of the ROS graph); `backend`
(`Ros2Backend`, which composes them). Importing this package does not
import rclpy: `create_backend` does, and turns a missing rclpy or control_msgs into
`BackendUnavailable` with the install hint (exit 2 at start-up). See
docs/backends/ros2.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from armwarden.backends.ros2.config import Config
from armwarden.core.errors import BackendUnavailable

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

#: how to get rclpy and the interfaces that are not on PyPI: in a venv of their own (the ROS
#: wheels re-execute every interpreter of their venv with ROS's libraries on LD_LIBRARY_PATH,
#: which the main venv's Pinocchio and MuJoCo must not see), as scripts/run.sh builds it
INSTALL_HINT = (
    "bash scripts/run.sh --backend ros2 --backend-config examples/ros2_fr3.yaml (in a checkout) builds "
    "the ROS venv .venv-ros and serves from it; a desktop client's command is then "
    ".venv-ros/bin/armwarden. By hand: ARMWARDEN_VENV=.venv-ros ARMWARDEN_EXTRAS=dev,can,ros "
    "ARMWARDEN_CONSTRAINTS=constraints/ros.txt bash scripts/bootstrap.sh && "
    ".venv-ros/bin/python scripts/build_ros_interfaces.py (never into the main .venv)"
)


def create_backend(robot: RobotModel, policy: Policy, config: Config) -> Backend:
    """Registry factory: the ROS 2 backend for `policy`'s joints with `config`'s names."""
    try:
        from armwarden.backends.ros2 import backend
    except ImportError as exc:
        raise BackendUnavailable(f"the ros2 backend is not available: {exc}; install it with: {INSTALL_HINT}") from exc
    return backend.create_backend(robot, policy, config)


__all__ = ["INSTALL_HINT", "Config", "create_backend"]
