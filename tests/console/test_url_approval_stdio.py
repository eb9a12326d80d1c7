"""URL-mode approvals with `armwarden serve` over stdio (a real subprocess, the console on
--console-port) and the SDK's stdio client, under both protocol revisions: the link arrives as
URL-mode elicitation (mid-call under 2025-11-25, in an InputRequiredResult under 2026-07-28),
the operator answers in the console, and execute_plan proceeds from that record only."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import anyio
import httpx2
import mcp_types as types
import pytest
import yaml
from mcp import Client, StdioServerParameters

from armwarden.policy import apply_overrides, bundled_policy
from armwarden.transport.tokens import TokenStore
from tests.console.served import csrf_of, sign_in
from tests.helpers import HOME, REPO, SRC, free_port, records_of, text_of
from tests.server.harness import MODES

pytestmark = pytest.mark.anyio

HOST = "127.0.0.1"
URL_POLICY = {"approval.mode": "always", "approval.channel": "url"}
GOAL = [0.3, *HOME[1:]]


def serve_params(tmp_path: Path, port: int) -> tuple[StdioServerParameters, str]:
    """The daemon's command line (url-channel policy, console on `port`) and an operator token."""
    policy = tmp_path / "policy.yaml"
    document = yaml.safe_load(bundled_policy("fr3").read_text())
    policy.write_text(yaml.safe_dump(apply_overrides(document, URL_POLICY)), encoding="utf-8")
    backend = tmp_path / "fake.yaml"
    backend.write_text("speedup: 20\n", encoding="utf-8")
    tokens = tmp_path / "tokens.json"
    operator = TokenStore.add(tokens, "operator", name="alice")
    params = StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--policy", str(policy), "--backend-config", str(backend),
              "--audit-log", str(tmp_path / "audit.jsonl"), "--console-port", str(port), "--auth-tokens", str(tokens),
              "--log-level", "WARNING"],
        env={"PYTHONPATH": str(SRC)},
        cwd=str(REPO),
    )
    return params, operator


def console_operator(base: str, token: str, decision: str, links: list[str]) -> Any:
    """An elicitation callback: alice answers the link in the console, then the client reports
    that the human opened it."""

    async def callback(context: Any, params: Any) -> types.ElicitResult:
        if getattr(params, "mode", "form") != "url":
            return types.ElicitResult(action="cancel")
        links.append(params.url)
        async with httpx2.AsyncClient(base_url=base, timeout=30) as http:
            await sign_in(http, token)
            path = params.url.removeprefix(base)
            page = await http.get(path)
            await http.post(path, data={"decision": decision, "csrf": csrf_of(page.text)})
        return types.ElicitResult(action="accept")

    return callback


async def plan_and_execute(tmp_path: Path, mode: str, decision: str) -> tuple[types.CallToolResult, list[float], list[str]]:
    port = free_port(HOST)
    params, operator = serve_params(tmp_path, port)
    links: list[str] = []
    with anyio.fail_after(60):
        async with Client(params, mode=mode,
                          elicitation_callback=console_operator(f"http://{HOST}:{port}", operator, decision, links)) as client:
            plan = await client.call_tool("plan_to_joints", {"joint_positions": GOAL})
            assert not plan.is_error, text_of(plan)
            result = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
            state = await client.call_tool("get_robot_state", {})
    return result, state.structured_content["joint_positions"], links


@pytest.mark.parametrize("mode", MODES)
async def test_approved_in_the_console_the_motion_runs(tmp_path: Path, mode: str) -> None:
    result, joints, links = await plan_and_execute(tmp_path, mode, "approve")

    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"] == {"required": True, "operator": "alice", "via": "console"}
    assert joints == pytest.approx(GOAL, abs=1e-6)
    assert len(links) == 1 and links[0].startswith(f"http://{HOST}:")


@pytest.mark.parametrize("mode", MODES)
async def test_declined_in_the_console_nothing_moves(tmp_path: Path, mode: str) -> None:
    result, joints, _ = await plan_and_execute(tmp_path, mode, "decline")

    assert result.is_error and "declined" in text_of(result)
    assert joints == pytest.approx(HOME, abs=1e-6)
    records = records_of(tmp_path / "audit.jsonl")
    assert [r["outcome"] for r in records if r["event"] == "console_approval"] == ["declined"]
    assert not any(r["event"] == "execution_started" for r in records)
