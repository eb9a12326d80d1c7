"""Fixtures of the CAN backend tests."""

from __future__ import annotations

import sys
from collections.abc import AsyncIterator

import pytest

from armwarden.backends.can.backend import CanBackend
from armwarden.daemon.startup import SWITCH_INTERVAL_S
from tests.backends.can.test_can_backend import build


@pytest.fixture
async def arm() -> AsyncIterator[CanBackend]:
    """The emulated RobStride arm of examples/can_sim.yaml, opened; closed after the test. The
    interpreter switches threads as `armwarden serve` makes it (`SWITCH_INTERVAL_S`): with the
    default 5 ms, the bus reader thread can wait several servo ticks for the interpreter lock,
    which the daemon does not let happen."""
    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    backend = build()
    try:
        await backend.open()
        try:
            yield backend
        finally:
            await backend.close()
    finally:
        sys.setswitchinterval(switch_interval)
