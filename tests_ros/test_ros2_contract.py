"""The backend contract on `--backend ros2` against the fake FR3 cell (real rclpy endpoints on
both sides), with the cell's goal counters showing that refused executions sent it nothing."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from tests.backends.contract import BackendContract

from armwarden.backends.base import Backend
from tests_ros.backend_setup import build_backend, example_config
from tests_ros.cell import Cell, CellConfig


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


class TestRos2ActionContract(BackendContract):
    """Trajectories through the FollowJointTrajectory action."""

    cell: Cell

    @pytest.fixture(autouse=True)
    def running_cell(self) -> Iterator[Cell]:
        with Cell(CellConfig()) as cell:
            self.cell = cell
            yield cell

    def build(self) -> Backend:
        return build_backend()

    def assert_nothing_reached_the_arm(self, backend: Backend) -> None:
        counters = self.cell.counters()
        assert counters.goals_received == 0 and counters.topic_trajectories == 0


class TestRos2TopicContract(TestRos2ActionContract):
    """Trajectories through the JointTrajectory topic fallback (stop = a one-point hold)."""

    def build(self) -> Backend:
        return build_backend(example_config(trajectory={"action": None, "topic": "/fr3_arm_controller/joint_trajectory"}))
