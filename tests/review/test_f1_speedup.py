"""Review of F1 (bda5577): the observer's interval cap on the arm's time, against a backend whose
sample period × speedup is at or over the cap. Every interval is then skipped: a free motion
with nothing touching reads as a lost reading."""

from __future__ import annotations

import anyio
import numpy as np
import pytest

from armwarden.backends.fake.backend import FakeBackend
from armwarden.safety.contact_source import JointTorqueContact
from tests.backends.test_fake import FR3_JOINT_NAMES, Q_REACH, Q_READY, straight_line
from tests.backends.test_joint_torques_fake import fr3, run  # noqa: F401 - the fixture
from tests.safety.test_joint_torque_monitor import mon_observer


@pytest.mark.parametrize("speedup", [20.0, 50.0])
def test_a_free_motion_on_a_fake_the_config_accepts_reads_finite(fr3, speedup: float) -> None:  # noqa: F811
    async def scenario(backend: FakeBackend) -> tuple[int, bool]:
        contact = JointTorqueContact(backend.read_joint_states_since, mon_observer(fr3), FR3_JOINT_NAMES,
                                     time_scale=backend.speedup, max_unobserved_s=0.1)
        await contact.read()
        finite = True
        async with anyio.create_task_group() as group:
            done = anyio.Event()

            async def move() -> None:
                await backend.execute(straight_line(Q_READY, Q_REACH, duration_s=10.0))
                done.set()

            group.start_soon(move)
            while not done.is_set():
                estimate = await contact.read()
                finite = finite and estimate is not None and bool(np.all(np.isfinite(estimate.force)))
                await anyio.sleep(0.005)
        return contact.samples_integrated, finite

    integrated, finite = run(scenario, speedup=speedup)
    assert finite, f"a free motion at speedup {speedup} read as a lost reading ({integrated} samples integrated)"
