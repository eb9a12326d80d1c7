"""The Backend template's state reads: a published snapshot is returned as is; without one the
read runs under the deadline; a backend that cannot read fails closed."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from armwarden.backends.base import Backend, Capabilities, ExecutionResult, JointState
from armwarden.errors import BackendError

NAMES = ("j1", "j2")


class _Probe(Backend):
    """A backend with no hardware: `published` is its snapshot, `_read_joint_state` may hang."""

    name = "probe"

    def __init__(self, published: JointState | None = None, hang_s: float = 0.0, broken: bool = False) -> None:
        super().__init__(NAMES, start_tolerance_rad=0.01)
        self.published, self.hang_s, self.broken = published, hang_s, broken
        self.slow_reads = 0

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities()

    async def _open(self) -> None:
        pass

    async def _close(self) -> None:
        pass

    def _latest_joint_state(self) -> JointState | None:
        if self.broken:
            raise BackendError("receive thread died")
        return self.published

    async def _read_joint_state(self) -> JointState:
        self.slow_reads += 1
        await asyncio.sleep(self.hang_s)
        return JointState(NAMES, np.zeros(2), np.zeros(2), 0.0)

    async def _execute(self, trajectory, progress) -> ExecutionResult:  # pragma: no cover - never moves
        raise AssertionError("the read tests never execute")

    async def _stop(self) -> None:
        pass

    def _stop_now(self) -> None:
        pass


def _read(backend: _Probe) -> JointState:
    async def scenario() -> JointState:
        await backend.open()
        try:
            return await backend.read_joint_state()
        finally:
            await backend.close()

    return asyncio.run(scenario())


def test_a_published_snapshot_is_returned_without_the_slow_read():
    snapshot = JointState(NAMES, np.array([0.1, 0.2]), np.zeros(2), 12.5)
    backend = _Probe(published=snapshot)
    assert _read(backend) is snapshot
    assert backend.slow_reads == 0


def test_without_a_snapshot_the_read_runs_under_the_deadline():
    backend = _Probe(hang_s=10.0)
    backend.read_timeout_s = 0.05
    with pytest.raises(TimeoutError):
        _read(backend)
    assert backend.slow_reads == 1


def test_a_backend_whose_snapshot_source_died_fails_the_read():
    with pytest.raises(BackendError, match="receive thread died"):
        _read(_Probe(broken=True))


def test_reads_before_open_are_refused():
    with pytest.raises(BackendError, match="not open"):
        asyncio.run(_Probe().read_joint_state())
