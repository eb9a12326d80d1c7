"""Commands run as a newcomer runs them: the README's lines, from the checkout, under the
environment an MCP client's stdio transport gives (the SDK passes only a minimal one), with set-up
that must not install anything (`ARMWARDEN_NO_INSTALL=1`: scripts/bootstrap.sh then fails instead
of reaching the network). Used by tests/test_readme_commands.py and the ROS lane's tests."""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

import anyio
from mcp import Client
from mcp.client.stdio import get_default_environment

from tests.helpers import HOME, REPO, text_of

README = REPO / "README.md"
#: nothing to install at run time: set-up happened before the tests (scripts/test.sh)
NO_INSTALL = {"ARMWARDEN_NO_INSTALL": "1", "PIP_NO_INDEX": "1", "UV_OFFLINE": "1"}
#: how long a first get_robot_state or plan may keep being refused (a stale stream on a loaded machine)
STATE_DEADLINE_S = 60.0


def readme_commands(text: str | None = None) -> list[list[str]]:
    """Every command line of the README's ```bash blocks (comments stripped), split as a shell would."""
    text = README.read_text(encoding="utf-8") if text is None else text
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            if words:
                commands.append(words)
    return commands


def readme_command(*prefix: str, backend: str | None = None) -> list[str]:
    """The one README command that starts with `prefix` (and serves `backend`, when given)."""
    found = [c for c in readme_commands() if c[:len(prefix)] == list(prefix)
             and (backend is None or ("--backend" in c and c[c.index("--backend") + 1] == backend))]
    assert len(found) == 1, f"README.md should show one command {' '.join(prefix)} (backend {backend}): {found}"
    return found[0]


def client_env(**extra: str) -> dict[str, str]:
    """What an MCP client's stdio transport passes (the SDK's minimal environment) plus `extra`,
    as a desktop client's "env" block would, and no installing."""
    return {**get_default_environment(), **NO_INSTALL, **extra}


async def until_ok(client: Client, tool: str, arguments: dict[str, Any]) -> Any:
    """`tool`'s result once it is not an error (a stale stream on a loaded machine is refused,
    fail closed: ask again), within `STATE_DEADLINE_S`; else the last error, failing the test."""
    deadline = anyio.current_time() + STATE_DEADLINE_S
    while True:
        result = await client.call_tool(tool, arguments)
        if not result.is_error or anyio.current_time() > deadline:
            break
        await anyio.sleep(0.2)
    assert not result.is_error, f"{tool}: {text_of(result)}"
    return result


async def first_contact(client: Client) -> dict[str, Any]:
    """What an agent does first: list the tools, read the state, plan a small move. Returns the plan."""
    tools = {tool.name for tool in (await client.list_tools()).tools}
    assert {"get_robot_state", "plan_to_joints", "execute_plan"} <= tools, tools
    positions = (await until_ok(client, "get_robot_state", {})).structured_content["joint_positions"]
    assert len(positions) == len(HOME)
    goal = [*positions[:-1], positions[-1] + 0.05]
    plan = await until_ok(client, "plan_to_joints", {"joint_positions": goal, "preview": False})
    assert plan.structured_content["status"] in ("ok", "needs_approval"), plan.structured_content
    return plan.structured_content


def cwd() -> Path:
    """Where the README's commands are typed: the checkout."""
    return REPO
