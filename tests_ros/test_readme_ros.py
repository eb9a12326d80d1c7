"""The README's two ROS 2 commands, exactly as written (parsed from README.md): the fake cell's
launcher, then the daemon's command driven through the official MCP SDK's stdio client with the
minimal environment it passes plus the `env` block the README's ROS client configuration shows
(this session's random ROS_DOMAIN_ID, LOCALHOST discovery), which both launchers must honour.
Nothing may be installed here (`ARMWARDEN_NO_INSTALL=1`); the audit log goes to tmp_path."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import anyio
import pytest
from mcp import Client, StdioServerParameters
from mcp.client.stdio import stdio_client
from tests.helpers import REPO, records_of, stop_process
from tests.launch import NO_INSTALL, client_env, first_contact, readme_command

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture
def readme_cell(tmp_path: Path) -> Iterator[Path]:
    """The README's cell command in this session's environment (its random domain); yields its stderr file."""
    err = tmp_path / "cell.err"
    env = {**os.environ, **NO_INSTALL}
    with err.open("w") as stderr:
        process = subprocess.Popen(readme_command("bash", "scripts/ros_cell.sh"), cwd=REPO, env=env,
                                   stdout=subprocess.PIPE, stderr=stderr, text=True)
    assert process.stdout is not None
    try:
        ready = process.stdout.readline()
        assert f"fake FR3 cell ready: ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}" in ready, ready + err.read_text()
        yield err
    finally:
        stop_process(process, 15)


async def test_the_readme_ros_commands_serve_a_client_on_the_same_domain(tmp_path: Path, readme_cell: Path) -> None:
    command = readme_command("bash", "scripts/run.sh", backend="ros2")
    audit, err = tmp_path / "audit.jsonl", tmp_path / "daemon.err"
    dds = {"ROS_DOMAIN_ID": os.environ["ROS_DOMAIN_ID"], "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    daemon = StdioServerParameters(command=command[0], args=[*command[1:], "--audit-log", str(audit)],
                                   env=client_env(**dds), cwd=str(REPO))

    with err.open("w") as errlog:
        async with Client(stdio_client(daemon, errlog=errlog)) as client:
            plan = await first_contact(client)

    assert plan["plan_id"].startswith("plan")
    said = f"ROS_DOMAIN_ID={dds['ROS_DOMAIN_ID']}, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST"
    cell_said, daemon_said = await anyio.Path(readme_cell).read_text(), await anyio.Path(err).read_text()
    assert said in cell_said and said in daemon_said, daemon_said
    assert "bootstrap: installing" not in daemon_said
    assert {"get_robot_state", "plan_to_joints"} <= {r["tool"] for r in records_of(audit) if r["event"] == "tool_call"}
