"""How the test harness builds the CAN backend (tests/server/harness.py looks this module up by name).

`build_for_tests(policy, robot, *, speedup, options)` is the one function every backend package's
`testing.py` has (docs/add-a-backend.md). The CAN backend under test is the emulated RobStride arm
of examples/can_sim.yaml (so it needs a source checkout) on a virtual bus of its own; `options`
are config keys over that document. python-can is imported only when the backend is built.
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from armwarden.backends import create_backend

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

#: the emulated RobStride arm the tests drive (the repository's example config)
CAN_SIM = Path(__file__).resolve().parents[4] / "examples" / "can_sim.yaml"


def build_for_tests(policy: Policy, robot: RobotModel, *, speedup: float, options: Mapping[str, Any]) -> Backend:
    """The emulated arm of `CAN_SIM` for `policy`, simulated at `speedup`, with `options` over it."""
    document = yaml.safe_load(CAN_SIM.read_text())
    document["bus"]["channel"] = f"armwarden-harness-{uuid.uuid4().hex}"  # virtual buses of one name share frames
    document["simulate"]["speedup"] = speedup
    # the test process stalls its threads far longer than a daemon (planning, a large heap, 2 cores
    # shared with other suites): watch for silence on a scale those stalls do not reach
    document |= {"rx_timeout_s": 1.0, "can_timeout_s": 2.0}
    return create_backend("can", robot, policy, document | dict(options))


__all__ = ["CAN_SIM", "build_for_tests"]
