"""The tiny example backend keeps the whole contract (see minimal_backend.py)."""

from __future__ import annotations

from armwarden.backends.base import Backend
from armwarden.robots import load_profile
from tests.backends.contract import BackendContract
from tests.backends.minimal_backend import MinimalBackend

_READY = load_profile("fr3").ready_joint_positions or {}
FR3_JOINT_NAMES, FR3_READY = tuple(_READY), tuple(_READY.values())


class TestMinimalBackendContract(BackendContract):
    def build(self) -> Backend:
        return MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)
