"""Fixtures of the CAN backend tests."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from armwarden.backends.can.backend import CanBackend
from tests.backends.can.test_can_backend import build


@pytest.fixture
async def arm() -> AsyncIterator[CanBackend]:
    """The emulated RobStride arm of examples/can_sim.yaml, opened; closed after the test."""
    backend = build()
    await backend.open()
    try:
        yield backend
    finally:
        await backend.close()
