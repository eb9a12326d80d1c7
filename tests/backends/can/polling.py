"""Waiting for something another thread does, without timing thresholds: poll until it holds."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable

#: generous: a loaded 2-core machine may stall threads for a long time; passing tests never wait this long
EVENTUALLY_S = 20.0


def eventually(condition: Callable[[], bool], what: str, timeout_s: float = EVENTUALLY_S) -> None:
    """Return once `condition()` holds; fail the test naming `what` if it never does."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"never happened: {what}")
        time.sleep(0.002)


def unique_channel() -> str:
    """A virtual-bus channel no other test uses (virtual buses with the same name talk to each other)."""
    return f"armwarden-test-{uuid.uuid4().hex}"
