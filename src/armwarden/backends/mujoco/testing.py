"""How the test harness builds the MuJoCo backend (tests/server/harness.py looks this module up by name).

`build_for_tests(policy, robot, *, speedup, options)` is the one function every backend package's
`testing.py` has (docs/add-a-backend.md); `options` are `Config` fields over the defaults.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from armwarden.backends import create_backend

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel


def build_for_tests(policy: Policy, robot: RobotModel, *, speedup: float, options: Mapping[str, Any]) -> Backend:
    """The simulated cell for `policy` at `speedup` (the default scene), with `options` over it."""
    return create_backend("mujoco", robot, policy, {"speedup": speedup} | dict(options))


__all__ = ["build_for_tests"]
