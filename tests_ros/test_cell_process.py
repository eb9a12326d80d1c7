"""`python -m tests_ros.cell` runs the cell as its own process, reachable on the test's domain."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from action_msgs.msg import GoalStatus

from tests_ros.cell import CellConfig
from tests_ros.client import RosClient, eventually

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def cell_process() -> Iterator[subprocess.Popen[str]]:
    """The standalone cell; it inherits the session's random domain and localhost discovery."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    process = subprocess.Popen(
        [sys.executable, "-m", "tests_ros.cell"], cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True
    )
    assert process.stdout is not None
    ready = process.stdout.readline()
    assert f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}" in ready
    yield process
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=15)


def test_a_client_in_another_process_moves_the_standalone_cell(cell_process: subprocess.Popen[str]) -> None:
    with RosClient(CellConfig()) as client:
        names = client.wait_latest("joint_states").name
        target = list(client.positions())
        target[0] += 0.2

        outcome = client.result(client.send_goal(client.trajectory_goal(names, [target], [0.3])))

        assert outcome.status == GoalStatus.STATUS_SUCCEEDED
        assert eventually(lambda: np.isclose(client.positions()[0], target[0]), what="joint states at the goal")


def test_the_standalone_cell_exits_cleanly_on_sigterm(cell_process: subprocess.Popen[str]) -> None:
    cell_process.send_signal(signal.SIGTERM)

    assert cell_process.wait(timeout=15) == 0
