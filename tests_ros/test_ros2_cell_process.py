"""The ROS 2 backend against the cell in another process (`python -m tests_ros.cell`): it moves
it, and when that process is killed mid-motion the execution aborts naming the cause and a fault
is reported."""

from __future__ import annotations

import re
import signal
import subprocess

import numpy as np
import pytest
from tests.backends.contract import straight_line

from armwarden.core.errors import BackendError
from tests_ros.backend_setup import opened
from tests_ros.test_cell_process import cell_process  # noqa: F401 - the standalone cell fixture

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


async def test_the_backend_moves_a_cell_in_another_process(cell_process: subprocess.Popen[str]) -> None:  # noqa: F811
    async with opened() as backend:
        q = (await backend.read_joint_state()).positions.copy()
        trajectory = straight_line(backend.joint_names, q, q + 0.2, 0.3)
        result = await backend.execute(trajectory)
    assert result.completed
    np.testing.assert_allclose(result.final_positions, trajectory.goal, rtol=0, atol=backend.goal_accuracy_rad)


async def test_a_cell_process_killed_mid_motion_aborts_the_execution_and_reports_a_fault(
        cell_process: subprocess.Popen[str]) -> None:  # noqa: F811
    async with opened() as backend:
        faults: list[str] = []
        backend.set_fault_listener(faults.append)
        q = (await backend.read_joint_state()).positions.copy()
        fractions: list[float] = []

        def kill_once_moving(fraction: float) -> None:
            fractions.append(fraction)
            if fraction > 0.05 and cell_process.poll() is None:
                cell_process.send_signal(signal.SIGKILL)

        with pytest.raises(BackendError) as aborted:
            await backend.execute(straight_line(backend.joint_names, q, q + 0.3, 3.0), kill_once_moving)
    # the abort follows the kill, never precedes it (a fault on a live cell would be a false alarm)
    assert cell_process.poll() is not None, f"aborted while the cell was alive: {aborted.value}"
    assert cell_process.wait(timeout=15) == -signal.SIGKILL
    assert re.search(r"execution aborted: (joint states on /joint_states stopped arriving"
                     r"|the trajectory action server .* vanished)", str(aborted.value)), str(aborted.value)
    assert faults and faults[0].startswith("ros2 backend fault: ")
