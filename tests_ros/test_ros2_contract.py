"""The backend contract on `--backend ros2` against the fake FR3 cell (real rclpy endpoints on
both sides), with the cell's goal counter showing that refused executions sent it nothing."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from tests.backends.contract import BackendContract

from armwarden.backends import parse_backend_config
from armwarden.backends.base import Backend
from armwarden.backends.ros2.backend import Ros2Backend, create_backend
from armwarden.backends.ros2.config import Config
from armwarden.policy import bundled_policy, load_policy
from armwarden.robot import build_robot
from tests_ros.cell import Cell, CellConfig

POLICY = load_policy(bundled_policy("fr3"))
ROBOT = build_robot(POLICY)
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ros2_fr3.yaml"


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def example_config(**changes: object) -> Config:
    """examples/ros2_fr3.yaml (the cell's names), with top-level keys replaced."""
    document = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    document.update(changes)
    config = parse_backend_config("ros2", document, str(EXAMPLE))
    assert isinstance(config, Config)
    return config


def build_backend(config: Config | None = None) -> Ros2Backend:
    return create_backend(ROBOT, POLICY, config or example_config())


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
