"""Every command of the README works exactly as written (parsed from README.md, so that a changed
README is tested as it now reads): the two set-up commands first, the demo as the next step, and
each backend's command (fake, MuJoCo, CAN; ROS 2 in tests_ros/test_readme_ros.py) driven through
the official MCP SDK's stdio client with the minimal environment it passes, as a desktop client
starts it. Set-up must find everything installed (scripts/test.sh installs before the lanes):
`ARMWARDEN_NO_INSTALL=1` makes bootstrap fail rather than install or reach the network. Each
daemon writes its audit log under tmp_path (`--audit-log`, the one argument added)."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest
from mcp import Client, StdioServerParameters
from mcp.client.stdio import stdio_client

from tests.helpers import REPO, records_of
from tests.launch import NO_INSTALL, README, client_env, first_contact, readme_command, readme_commands

pytestmark = pytest.mark.anyio

PLACEHOLDER = "/ABSOLUTE/PATH/TO/"


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def test_the_readme_opens_with_the_two_set_up_commands_then_the_demo() -> None:
    assert readme_commands()[:3] == [["bash", "scripts/run.sh"], ["bash", "scripts/test.sh"],
                                     [".venv/bin/python", "scripts/demo.py"]]


def test_the_readme_says_the_first_command_waits_for_a_client_on_stdin() -> None:
    opening = README.read_text(encoding="utf-8").split("## ")[0]

    assert "waits for an MCP client on stdin" in opening


def test_the_demo_runs_as_written(tmp_path: Path) -> None:
    env = {**os.environ, **NO_INSTALL}
    env.pop("ARMWARDEN_AUDIT_KEY", None)

    result = subprocess.run(readme_commands()[2], cwd=REPO, env=env, stdin=subprocess.DEVNULL, capture_output=True,
                            text=True, timeout=300)

    assert result.returncode == 0, result.stdout + result.stderr
    assert "All steps behaved as expected" in result.stdout


def backend_command(backend: str) -> list[str]:
    """The README's command for `backend`; the fake one is the very first command, with no argument."""
    if backend == "fake":
        return readme_commands()[0]
    return readme_command("bash", "scripts/run.sh", backend=backend)


@pytest.mark.parametrize("backend", ["fake", "mujoco", "can"])
async def test_the_readme_command_of_each_backend_serves_a_client(tmp_path: Path, backend: str) -> None:
    command = backend_command(backend)
    audit, err = tmp_path / "audit.jsonl", tmp_path / "daemon.err"
    daemon = StdioServerParameters(command=command[0], args=[*command[1:], "--audit-log", str(audit)],
                                   env=client_env(), cwd=str(REPO))

    with err.open("w") as errlog:
        async with Client(stdio_client(daemon, errlog=errlog)) as client:
            plan = await first_contact(client)

    assert plan["plan_id"].startswith("plan")
    assert f"backend {backend} opened" in err.read_text(), err.read_text()
    assert "bootstrap: installing" not in err.read_text()
    tools = {r["tool"] for r in records_of(audit) if r["event"] == "tool_call"}
    assert {"get_robot_state", "plan_to_joints"} <= tools  # every call on record, in the tmp log


# ------------------------------------------------------------------ the "Connect your client" block
def client_blocks() -> list[dict]:
    """The README's ```json blocks: one `mcpServers` configuration each."""
    text = README.read_text(encoding="utf-8")
    return [json.loads(block) for block in re.findall(r"```json\n(.*?)```", text, flags=re.S)]


def claude_code_commands() -> list[list[str]]:
    return [c for c in readme_commands() if c[:3] == ["claude", "mcp", "add"]]


def serve_args(command: list[str]) -> list[str]:
    return command[command.index("serve"):]


def test_the_readme_shows_a_desktop_block_and_a_claude_code_command_for_the_fake_and_ros_backends() -> None:
    servers = [server for block in client_blocks() for server in block["mcpServers"].values()]
    ros = [s for s in servers if "ros2" in s["args"]]
    plain = [s for s in servers if "ros2" not in s["args"]]

    assert plain and ros
    assert all(s["command"].startswith(PLACEHOLDER) and s["args"][0] == "serve" for s in servers)
    assert all(s["command"].endswith("/.venv/bin/armwarden") for s in plain)
    assert all(s["command"].endswith("/.venv-ros/bin/armwarden") for s in ros)
    assert all(set(s["env"]) >= {"ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"} for s in ros)
    commands = claude_code_commands()
    assert {("ros2" in c) for c in commands} == {True, False}
    for command in commands:
        exe = command[command.index("--") + 1]
        assert exe.startswith(PLACEHOLDER) and command[command.index("--") + 2] == "serve"
        if "ros2" in command:
            env = [command[i + 1] for i, word in enumerate(command) if word == "-e"]
            assert {e.split("=")[0] for e in env} >= {"ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"}


def test_the_readme_client_configurations_carry_no_shell_expression() -> None:
    """Clients that do not expand `${...}` pass it on literally (see examples/ and the daemon's refusal)."""
    text = "\n".join(json.dumps(b) for b in client_blocks()) + "\n".join(shlex.join(c) for c in claude_code_commands())

    assert "${" not in text and "$(" not in text


def test_the_desktop_block_runs_from_a_checkout_with_the_placeholder_filled_in(tmp_path: Path) -> None:
    """The fake block's command and args, with this checkout for the placeholder, start a daemon
    that opens its backend and its log, and stops cleanly at the end of its input."""
    server = next(s for b in client_blocks() for s in b["mcpServers"].values() if "ros2" not in s["args"])
    args = [a.replace(PLACEHOLDER + "armwarden-audit.jsonl", str(tmp_path / "audit.jsonl"))
             .replace(PLACEHOLDER + "armwarden", str(REPO)) for a in server["args"]]
    command = server["command"].replace(PLACEHOLDER + "armwarden", str(REPO))

    result = subprocess.run([command, *args], cwd=tmp_path, env=client_env(), stdin=subprocess.DEVNULL,
                            capture_output=True, text=True, timeout=120)

    assert result.returncode == 0, result.stderr
    assert records_of(tmp_path / "audit.jsonl")[-1]["event"] == "shutdown"
