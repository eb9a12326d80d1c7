"""Fixtures of the planning tests: the runtime model (planner, envelope, detour planner) of the bundled policy."""

from __future__ import annotations

import pytest

from armwarden.policy import Policy
from armwarden.preflight import RuntimeModel, load_runtime_model


@pytest.fixture(scope="session")
def runtime(fr3_policy: Policy) -> RuntimeModel:
    return load_runtime_model(fr3_policy)
