"""How the test harness builds the fake backend (tests/server/harness.py looks this module up by name).

Every backend package's `testing.py` has the one function `build_for_tests(policy, robot, *,
speedup, options)`; docs/add-a-backend.md describes the convention. The fake's `options` are
either `Config` fields, which configure it, or its fault-injection attributes (`fail_stop=True`,
`stall_wrench_s=0.3`, ...: backend.py's docstring), set on the built backend.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from armwarden.backends import create_backend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.fake.config import Config

if TYPE_CHECKING:
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel


def build_for_tests(policy: Policy, robot: RobotModel, *, speedup: float, options: Mapping[str, Any]) -> FakeBackend:
    """The fake for `policy` at `speedup`; an option that is neither a `Config` field nor an
    attribute of the fake is refused (a misspelt fault would silently test nothing)."""
    config = {key: value for key, value in options.items() if key in Config.model_fields}
    fake = create_backend("fake", robot, policy, {"speedup": speedup} | config)
    assert isinstance(fake, FakeBackend)
    for key, value in options.items():
        if key not in config:
            if not hasattr(fake, key):
                raise TypeError(f"the fake backend has no option or attribute {key!r}")
            setattr(fake, key, value)
    return fake


__all__ = ["build_for_tests"]
