"""The CAN backend asked whether it is why the wrench went stale (`fault_behind_stale_data`).

Silent actuators stop the joint states and the wrench together; the force monitor's wrench
timeout can see it before the servo loop's RX timeout does. Asked then, the backend must wait for
its own verdict instead of answering "no fault of my own" (found by the evaluation's backend
death: with the emulator stopped, the Guard recorded the wrench alone as lost).
"""

from __future__ import annotations

import anyio
import pytest

from armwarden.backends.can.backend import CanBackend

pytestmark = pytest.mark.anyio


async def test_a_bus_that_answers_is_not_the_cause(arm: CanBackend) -> None:
    assert await arm.fault_behind_stale_data() is None


async def test_every_actuator_gone_silent_is_the_cause(arm: CanBackend) -> None:
    arm.inject_death()  # the emulator stops: no actuator answers any more
    with anyio.fail_after(arm.config.rx_timeout_s + 10):
        cause = await arm.fault_behind_stale_data()
    assert cause is not None and "no reply for" in cause, cause
