"""How the test harness builds the ROS 2 backend (tests/server/harness.py looks this module up by name).

`build_for_tests(policy, robot, *, speedup, options)` is the one function every backend package's
`testing.py` has (docs/add-a-backend.md). The backend under test is wired as examples/ros2_fr3.yaml
(so it needs a source checkout), whose names the fake FR3 cell `armwarden.backends.ros2.fake_cell.Cell` mirrors; the
harness starts that cell. `speedup` is ignored: the cell interpolates goals in real time. rclpy is
imported only when the backend is built.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from armwarden.backends import create_backend
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

#: the ROS 2 wiring of a ros2_control FR3, whose names the fake cell's defaults mirror
ROS2_FR3 = Path(__file__).resolve().parents[4] / "examples" / "ros2_fr3.yaml"


def build_for_tests(policy: Policy, robot: RobotModel, *, speedup: float, options: Mapping[str, Any]) -> Backend:
    """The backend of `ROS2_FR3` for `policy`, with `options` over it (`speedup`: see the module docstring)."""
    document = yaml.safe_load(ROS2_FR3.read_text())
    # the cell publishes from a thread of the test process, which stalls far longer than a daemon
    # (planning, a large heap, 2 cores shared with other suites): ages on a scale those stalls do not reach
    document["joint_states"]["max_age_s"] = 1.0
    document["wrench"]["max_age_s"] = MAX_WRENCH_TIMEOUT_S
    # no guardian process per harness test (a second of rclpy start-up each); its own tests, and
    # every daemon a test starts from examples/ros2_fr3.yaml, have it
    document["guardian"] = None
    return create_backend("ros2", robot, policy, document | dict(options))


__all__ = ["ROS2_FR3", "build_for_tests"]
