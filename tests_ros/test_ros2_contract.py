"""The backend contract on `--backend ros2` against the fake FR3 cell (real rclpy endpoints on
both sides), with the cell's goal counters showing that refused executions sent it nothing."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from tests.backends.contract import BackendContract

from armwarden.backends import parse_backend_config
from armwarden.backends.base import Backend
from armwarden.backends.ros2.config import Config
from tests_ros.backend_setup import EXAMPLE, build_backend, example_document
from tests_ros.cell import Cell, CellConfig

#: the cell and the backend share this test process: beside the other lane and two CPU hogs its
#: joint states were seen 0.54-0.81 s apart, and that stale-state fault beat the worker fault the
#: contract checks (a dead or hung executor). 1.0 s, as the daemon tests allow (test_daemon_ros2.py).
LOADED_HOST_JOINT_STATES_MAX_AGE_S = 1.0


def contract_config(**changes: object) -> Config:
    """examples/ros2_fr3.yaml with top-level keys replaced and the joint states' max age above."""
    document = example_document(**changes)
    document["joint_states"] = {**document["joint_states"], "max_age_s": LOADED_HOST_JOINT_STATES_MAX_AGE_S}
    config = parse_backend_config("ros2", document, str(EXAMPLE))
    assert isinstance(config, Config)
    return config


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
        return build_backend(contract_config())

    def assert_nothing_reached_the_arm(self, backend: Backend) -> None:
        counters = self.cell.counters()
        assert counters.goals_received == 0 and counters.topic_trajectories == 0


class TestRos2TopicContract(TestRos2ActionContract):
    """Trajectories through the JointTrajectory topic fallback (stop = a one-point hold)."""

    def build(self) -> Backend:
        return build_backend(contract_config(trajectory={"action": None, "topic": "/fr3_arm_controller/joint_trajectory"}))
