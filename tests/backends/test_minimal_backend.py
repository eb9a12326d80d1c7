"""The tiny example backend keeps the whole contract (see minimal_backend.py)."""

from __future__ import annotations

from armwarden.backends.base import Backend
from armwarden.backends.fake import FR3_JOINT_NAMES, FR3_READY
from tests.backends.contract import BackendContract
from tests.backends.minimal_backend import MinimalBackend


class TestMinimalBackendContract(BackendContract):
    def build(self) -> Backend:
        return MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)
