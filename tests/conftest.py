"""Shared fixtures: the bundled FR3 policy, robot model, envelope and planner; a clean audit-key environment.

Habits of this suite:

- Async tests are `async def` with `@pytest.mark.anyio` (anyio's pytest plugin) on the asyncio
  backend (`anyio_backend` below); no test calls `anyio.run` itself unless it must stay sync
  (a comment says why there).
- Shared helpers are in `tests/helpers.py` (poses, `text_of`, `records_of`, `FakeClock`, child
  process environment) and `tests/server/harness.py` (an in-memory ArmWarden and its SDK clients).
- Hypothesis budgets: the default run (`pytest -m "not slow"`) must stay fast, so the slowest
  properties run there with a small `max_examples`, and again under the same name with a
  `_full_budget` suffix, marked `slow`, with the full budget: `pytest -m slow` runs the full
  budgets (see the dense-resampling properties in `safety/test_envelope.py`). A property is given
  a quick/full pair when one example costs more than about 0.1 s.
- Real-time tests (the CAN emulator's wall-clock physics and servo loop: everything under
  `tests/backends/can/`, every test parametrized with the `can` backend, and any test marked
  `realtime`) can be run apart from the rest: `ARMWARDEN_TEST_REALTIME=only` keeps just them,
  `=skip` keeps all but them. `scripts/test.sh` runs them first, alone on the machine, because a
  starved servo thread fails closed (a fault, a stopped motion) where a quiet one passes.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from armwarden.audit import AUDIT_KEY_ENV
from armwarden.planning.planners import Planner, PlannerSettings
from armwarden.policy import Policy, bundled_policy, load_policy
from armwarden.robot import RobotModel, build_robot
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import EnvelopeLimits
from tests.helpers import READY

REALTIME_ENV = "ARMWARDEN_TEST_REALTIME"
CAN_TESTS = Path(__file__).parent / "backends" / "can"


def is_realtime(item: pytest.Item) -> bool:
    """Whether the test runs the CAN emulator's wall-clock loop (or is marked `realtime`)."""
    if item.get_closest_marker("realtime") is not None or item.path.is_relative_to(CAN_TESTS):
        return True
    params = getattr(item, "callspec", None)
    return params is not None and any(isinstance(v, str) and v == "can" for v in params.params.values())


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Keep only the real-time tests, or all but them, as ARMWARDEN_TEST_REALTIME says."""
    choice = os.environ.get(REALTIME_ENV, "")
    if not choice:
        return
    if choice not in ("only", "skip"):
        raise pytest.UsageError(f"{REALTIME_ENV} must be 'only' or 'skip', not {choice!r}")
    keep = [item for item in items if is_realtime(item) == (choice == "only")]
    dropped = [item for item in items if is_realtime(item) != (choice == "only")]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = keep


@pytest.fixture(autouse=True)
def _the_can_emulator_runs_only_in_the_realtime_lane(monkeypatch: pytest.MonkeyPatch) -> None:
    """With ARMWARDEN_TEST_REALTIME=skip, a test that starts the CAN emulator in this process fails,
    naming the fix: `is_realtime` missed it, and it would run beside other tests on a shared core."""
    if os.environ.get(REALTIME_ENV) != "skip":
        return
    from armwarden.backends.can.emulator import ActuatorEmulator

    def refuse(self: ActuatorEmulator) -> None:
        pytest.fail(f"this test starts the CAN emulator outside the realtime lane ({REALTIME_ENV}=skip): mark it "
                    "`@pytest.mark.realtime` (or parametrize it with 'can'; see tests/conftest.py)")

    monkeypatch.setattr(ActuatorEmulator, "start", refuse)


@pytest.fixture
def anyio_backend() -> str:
    """`@pytest.mark.anyio` tests run on asyncio (the daemon's loop)."""
    return "asyncio"


@pytest.fixture(autouse=True)
def _no_audit_key_from_the_developer(monkeypatch: pytest.MonkeyPatch) -> None:
    """A developer's own ARMWARDEN_AUDIT_KEY must not key the logs tests write or verify.

    Tests that want a key set it themselves (`monkeypatch.setenv`), after this has run; child
    processes started from a test inherit the cleaned environment.
    """
    monkeypatch.delenv(AUDIT_KEY_ENV, raising=False)


def bundled_policy_path(name: str) -> Path:
    return bundled_policy(name)


@pytest.fixture(scope="session")
def fr3_policy() -> Policy:
    return load_policy(bundled_policy_path("fr3"))


@pytest.fixture(scope="session")
def robot(fr3_policy: Policy) -> RobotModel:
    return build_robot(fr3_policy)


@pytest.fixture(scope="session")
def limits(fr3_policy: Policy) -> EnvelopeLimits:
    return EnvelopeLimits.from_policy(fr3_policy)


@pytest.fixture(scope="session")
def envelope(robot: RobotModel, limits: EnvelopeLimits) -> Envelope:
    return Envelope(robot, limits)


@pytest.fixture(scope="session")
def planner(robot: RobotModel, fr3_policy: Policy) -> Planner:
    return Planner(robot, PlannerSettings.from_policy(fr3_policy))


@pytest.fixture
def ready() -> np.ndarray:
    return READY.copy()
