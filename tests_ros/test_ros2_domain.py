"""The cell and the daemon agree on the DDS domain and discovery range, or say how to: both
started with nothing set (a desktop client's minimal environment) meet on the same defaults and
name them on stderr; a daemon that hears no joint state names its domain and range and how to
make them agree. Both are started by their launchers (scripts/ros_cell.sh, scripts/run.sh
--backend ros2), which must not install anything here."""

from __future__ import annotations

import os
import random
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from mcp import Client, StdioServerParameters
from mcp.client.stdio import stdio_client
from tests.helpers import REPO, stop_process
from tests.launch import NO_INSTALL, client_env, first_contact

pytestmark = pytest.mark.anyio

ROS_VARIABLES = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS")
DEFAULTS = "ROS_DOMAIN_ID=0 (unset: the default), ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (unset: the default)"


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def without_ros_settings() -> dict[str, str]:
    env = {**os.environ, **NO_INSTALL}
    for name in (*ROS_VARIABLES, "ARMWARDEN_AUDIT_KEY"):
        env.pop(name, None)
    return env


@pytest.fixture
def default_cell(tmp_path: Path) -> Iterator[Path]:
    """scripts/ros_cell.sh with no ROS variable set; yields the file its stderr goes to."""
    err = tmp_path / "cell.err"
    with err.open("w") as stderr:
        process = subprocess.Popen(["bash", "scripts/ros_cell.sh"], cwd=REPO, env=without_ros_settings(),
                                   stdout=subprocess.PIPE, stderr=stderr, text=True)
    assert process.stdout is not None
    try:
        ready = process.stdout.readline()
        assert "fake FR3 cell ready: ROS_DOMAIN_ID=0" in ready, ready + err.read_text()
        yield err
    finally:
        stop_process(process, 15)


async def test_cell_and_daemon_started_with_nothing_set_meet_on_the_same_named_defaults(tmp_path, default_cell) -> None:
    daemon_err = tmp_path / "daemon.err"
    daemon = StdioServerParameters(
        command="bash",
        args=["scripts/run.sh", "--backend", "ros2", "--backend-config", "examples/ros2_fr3.yaml",
              "--audit-log", str(tmp_path / "audit.jsonl")],
        env=client_env(), cwd=str(REPO))  # the SDK's minimal environment: no ROS variable at all
    with daemon_err.open("w") as errlog:
        async with Client(stdio_client(daemon, errlog=errlog)) as client:
            plan = await first_contact(client)

    assert plan["plan_id"]
    assert DEFAULTS in default_cell.read_text()
    assert f"ros2: node armwarden started: {DEFAULTS}" in daemon_err.read_text()
    assert "bootstrap: installing" not in daemon_err.read_text()


def test_a_daemon_that_hears_no_joint_state_names_its_domain_and_range_and_how_to_agree(tmp_path: Path) -> None:
    config = yaml.safe_load((REPO / "examples" / "ros2_fr3.yaml").read_text())
    config["joint_states"]["startup_timeout_s"] = 1.0
    (tmp_path / "ros2.yaml").write_text(yaml.safe_dump(config))
    domain = random.randint(150, 232)  # no cell of the suite is there (they use 1..100 and 0)
    env = {**without_ros_settings(), "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

    result = subprocess.run(["bash", "scripts/run.sh", "--backend", "ros2", "--backend-config", str(tmp_path / "ros2.yaml"),
                             "--audit-log", str(tmp_path / "audit.jsonl")], cwd=REPO, env=env, stdin=subprocess.DEVNULL,
                            capture_output=True, text=True, timeout=180)

    assert result.returncode == 2, result.stderr
    assert "no joint state naming" in result.stderr, result.stderr
    assert f"ROS_DOMAIN_ID={domain}, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in result.stderr
    assert "same ROS_DOMAIN_ID" in result.stderr

