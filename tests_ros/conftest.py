"""Fixtures for tests against real rclpy endpoints.

Every test session picks a random ``ROS_DOMAIN_ID`` and limits DDS discovery to this host
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in ``os.environ``, before any rclpy context exists,
so the test process and every child process it starts stay off the LAN.
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator

import pytest

try:
    import control_msgs.action  # noqa: F401  (checked here so the hint below names the fix)
    import rclpy  # noqa: F401
except ImportError as exc:  # pragma: no cover - environment problem, not a test outcome
    raise ImportError(
        "tests_ros needs the ROS 2 wheels and the built interfaces, in .venv-ros: "
        "bash scripts/setup_ros.sh, then run them with .venv-ros/bin/python"
    ) from exc

from tests_ros.cell import Cell, CellConfig
from tests_ros.client import RosClient
from tests_ros.domains import TEST_DOMAIN_ENV


@pytest.fixture(scope="session", autouse=True)
def ros_local_domain() -> Iterator[int]:
    """A random domain id (the one `tests_ros.domains` gave this xdist worker, when loaded) and
    localhost-only discovery for this process and its children."""
    chosen = os.environ.get(TEST_DOMAIN_ENV, "")
    domain = int(chosen) if chosen.isdigit() else random.randint(1, 100)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("ROS_DOMAIN_ID", str(domain))
        patch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        patch.delenv("ROS_STATIC_PEERS", raising=False)
        patch.delenv("ROS_LOCALHOST_ONLY", raising=False)  # deprecated in Jazzy; the range above rules
        yield domain


@pytest.fixture
def cell_config() -> CellConfig:
    """Override in a test module (or parametrise) to change the cell."""
    return CellConfig()


@pytest.fixture
def cell(cell_config: CellConfig) -> Iterator[Cell]:
    """The fake FR3 cell in this process (its own rclpy context and executor thread)."""
    with Cell(cell_config) as running:
        yield running


@pytest.fixture
def client(cell: Cell) -> Iterator[RosClient]:
    """A plain rclpy client (not the backend) connected to the cell's endpoints."""
    with RosClient(cell.config) as running:
        yield running
