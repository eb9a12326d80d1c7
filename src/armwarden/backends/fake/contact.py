"""The fake cell's contact parts: the wrench the servo thread publishes (the virtual table's push),
the collision thresholds of the arm's reflex, and the recovery from the error a reflex latches.

Their fault injections and records live in `FakeKnobs`: `stall_wrench_s` makes wrench reads slow,
`collision_thresholds` records the last thresholds set, `fault` is the latched error, and every
threshold change or recovery counts as an actuation before its checks.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import anyio

from armwarden.backends.fake.knobs import FakeKnobs
from armwarden.backends.parts import CollisionThresholds, ErrorRecovery, WrenchSensor
from armwarden.core.errors import BackendError
from armwarden.core.state import Wrench


class FakeWrench(WrenchSensor):
    """The contact force the servo thread computed; a stalled sensor (`stall_wrench_s`) publishes
    nothing, so reads take the slow path, under the read deadline."""

    def __init__(self, sample: Callable[[], Wrench], knobs: FakeKnobs) -> None:
        self._sample = sample  # the published sample (raises if the control thread is gone)
        self._knobs = knobs

    def latest(self) -> Wrench | None:
        if self._knobs.stall_wrench_s > 0:
            return None
        return self._sample()

    async def read(self) -> Wrench | None:
        if self._knobs.stall_wrench_s > 0:
            await anyio.sleep(self._knobs.stall_wrench_s)
        return self._sample()


class FakeThresholds(CollisionThresholds):
    """Collision thresholds that are only recorded (`FakeKnobs.collision_thresholds`)."""

    def __init__(self, knobs: FakeKnobs) -> None:
        self._knobs = knobs

    async def set(self, force_n: float, torque_nm: float) -> None:
        self._knobs.count_actuation()
        if not (math.isfinite(force_n) and force_n > 0 and math.isfinite(torque_nm) and torque_nm > 0):
            raise BackendError(f"collision thresholds must be finite and > 0, got {force_n} N, {torque_nm} N·m")
        self._knobs.collision_thresholds = (float(force_n), float(torque_nm))


class FakeRecovery(ErrorRecovery):
    """Clears the latched `FakeKnobs.fault`, while the control thread runs."""

    def __init__(self, require_running: Callable[[], None], knobs: FakeKnobs) -> None:
        self._require_running = require_running
        self._knobs = knobs

    async def recover(self) -> None:
        self._knobs.count_actuation()
        self._require_running()
        self._knobs.fault = False
        self._knobs.fault_reason = ""


__all__ = ["FakeRecovery", "FakeThresholds", "FakeWrench"]
