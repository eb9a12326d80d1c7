"""Fixtures of the end-to-end scenario suite: every scenario runs once per harness backend.

`backend` is parametrised over `tests.server.harness.BACKENDS`, so a backend added there runs the
whole suite. `arm` is the daemon on that backend behind the SDK client (`arm_harness`), with the
bundled policy adapted to what the backend declares and changed by the test's
`@pytest.mark.policy(**{"dotted.path": value})`. A scenario that needs an optional capability says
so with `@pytest.mark.needs("gripper")` and is skipped only on a backend whose cell lacks that part
— never by backend name.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from armwarden.backends.parts import Capabilities
from armwarden.policy import Policy, bundled_policy, load_policy
from tests.server.harness import BACKENDS, ArmHarness, arm_harness, policy_with

# the harness builds its backends here; the suite asks the unopened backend what it declares
from tests.server.harness import _backend as _unopened_backend


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "policy(**overrides): dotted-path changes to the bundled policy for this scenario")
    config.addinivalue_line("markers", "needs(*capabilities): Capabilities fields the scenario needs (skipped without)")


@pytest.fixture
def anyio_backend() -> str:
    """The scenarios run on asyncio (the daemon's event loop)."""
    return "asyncio"


@pytest.fixture(params=BACKENDS, ids=BACKENDS)
def backend(request: pytest.FixtureRequest) -> str:
    """The name of the harness backend the scenario runs on."""
    return request.param


@pytest.fixture(scope="session")
def capabilities_of() -> Callable[[str], Capabilities]:
    """What each harness backend declares, asked once per backend of an unopened instance."""
    cache: dict[str, Capabilities] = {}
    fr3 = load_policy(bundled_policy("fr3"))

    def capabilities(name: str) -> Capabilities:
        if name not in cache:
            cache[name] = _unopened_backend(name, fr3, {}).capabilities
        return cache[name]

    return capabilities


@pytest.fixture
def capabilities(backend: str, capabilities_of: Callable[[str], Capabilities], request: pytest.FixtureRequest) -> Capabilities:
    """The backend's capabilities; skips the scenario when it lacks one its `needs` marker names."""
    declared = capabilities_of(backend)
    for marker in request.node.iter_markers("needs"):
        for name in marker.args:
            if not getattr(declared, name):
                pytest.skip(f"the {backend} backend's cell has no {name} part")
    return declared


@pytest.fixture
def goal_tolerance_rad(arm: ArmHarness) -> float:
    """How far the backend may end from a plan's goal [rad]: what it declares
    (`goal_accuracy_rad`), and never less than JSON's float round trip."""
    return max(arm.inner.goal_accuracy_rad, 1e-9)


def scenario_policy(capabilities: Capabilities, overrides: dict[str, Any]) -> Policy:
    """The bundled FR3 policy for a backend with `capabilities`: with neither a wrench estimate nor
    measured joint torques the motion runs unmonitored (as the harness does for such a backend),
    then the test's overrides."""
    monitored = capabilities.wrench or capabilities.joint_torques
    return policy_with(**{"force.require_wrench": monitored, **overrides})


@pytest.fixture
async def arm(backend: str, capabilities: Capabilities, tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[ArmHarness]:
    """The daemon on `backend`; on exit the harness verifies the audit chain the scenario left."""
    overrides: dict[str, Any] = {}
    for marker in reversed(list(request.node.iter_markers("policy"))):  # the closest marker wins
        overrides.update(marker.kwargs)
    async with arm_harness(tmp_path, scenario_policy(capabilities, overrides), backend=backend) as harness:
        yield harness
