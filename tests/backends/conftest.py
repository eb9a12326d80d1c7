"""Backend tests run their async tests on asyncio (the daemon's event loop)."""

from __future__ import annotations

import pytest


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"
