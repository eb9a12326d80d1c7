"""The ROS 2 backend: any ros2_control arm through standard interfaces, over real rclpy.

One job per module: `config` (the strict `--backend-config`; no rclpy), `bridge` (a private rclpy
context, node and executor thread; rclpy futures awaited from asyncio), `state` (thread-safe
caches of joint states and wrench with their receipt times), `images` (sensor_msgs images to
PNG), `tf` (a small transform buffer), `backend` (`Ros2Backend`). Importing this package does not
import rclpy: `create_backend` does, and turns a missing rclpy or control_msgs into
`BackendUnavailable` with the install hint (exit 2 at start-up). See docs/architecture.md,
section "Backends".
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from armwarden.backends.ros2.config import Config
from armwarden.errors import BackendUnavailable

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

#: how to get rclpy and the interfaces that are not on PyPI
INSTALL_HINT = "pip install -e '.[ros]' -c constraints/ros.txt && python scripts/build_ros_interfaces.py"


def create_backend(robot: RobotModel, policy: Policy, config: Config) -> Backend:
    """Registry factory: the ROS 2 backend for `policy`'s joints with `config`'s names."""
    try:
        from armwarden.backends.ros2 import backend
    except ImportError as exc:
        raise BackendUnavailable(f"the ros2 backend is not available: {exc}; install it with: {INSTALL_HINT}") from exc
    return backend.create_backend(robot, policy, config)


__all__ = ["INSTALL_HINT", "Config", "create_backend"]
