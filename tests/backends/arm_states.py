"""Waiting for a backend to report an arm state (shared by the arm-state tests of every backend)."""

from __future__ import annotations

import asyncio
import time

from armwarden.backends.arm_state import ArmState
from armwarden.backends.base import Backend

#: how long a test waits for a state before it reads what is reported [s]: generous, never a timing claim
DEADLINE_S = 10.0


async def reaches(backend: Backend, state: ArmState) -> ArmState:
    """Wait (generous deadline) until `backend` reports `state`; return what it reports."""
    deadline = time.monotonic() + DEADLINE_S
    while backend.arm_state is not state:
        if time.monotonic() > deadline:
            break
        await asyncio.sleep(0.002)
    return backend.arm_state
