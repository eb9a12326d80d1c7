"""`armwarden serve --transport http` as a real subprocess on 127.0.0.1, driven by the SDK's
streamable HTTP client: bearer tokens and roles, Host validation, plan + approved execute in both
protocol modes, and SIGTERM with a verifiable audit log naming the HTTP principals.

One daemon per module (start-up costs ~2 s). Tests that change shared state (an observer's
e-stop) put it back; the SIGTERM test comes last and makes its own calls first.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import anyio
import httpx2
import pytest
from mcp import Client, MCPError
from mcp.client.streamable_http import streamable_http_client

from tests.helpers import CLI, HOME, REPO, child_env, records_of, text_of, wait_for_record
from tests.server.harness import MODES
from tests.server.harness import approve as approving
from tests.server.http_daemon import Daemon, RawSession, add_token, http_daemon, session


@pytest.fixture(scope="module")
def daemon(tmp_path_factory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("http-daemon"), speedup=20) as running:
        yield running


if sys.version_info < (3, 11):  # pragma: no cover - the backport anyio installs on 3.10
    from exceptiongroup import BaseExceptionGroup


def leaves(error: BaseException) -> list[BaseException]:
    if isinstance(error, BaseExceptionGroup):
        return [leaf for inner in error.exceptions for leaf in leaves(inner)]
    return [error]


# ------------------------------------------------------------------ authentication and Host
@pytest.mark.parametrize("token", [None, "aw_not-a-real-token"], ids=["no_token", "wrong_token"])
def test_http_requests_without_a_valid_bearer_token_are_rejected_with_401(daemon, token) -> None:
    headers = {"Accept": "application/json, text/event-stream"}
    if token is not None:
        headers["Authorization"] = f"Bearer {token}"
    initialize = {"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
        "protocolVersion": "2025-11-25", "capabilities": {}, "clientInfo": {"name": "raw", "version": "1"}}}
    response = httpx2.post(daemon.url, json=initialize, headers=headers, timeout=5)
    assert response.status_code == 401
    assert response.headers["www-authenticate"].startswith("Bearer")


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("token", [None, "aw_not-a-real-token"], ids=["no_token", "wrong_token"])
async def test_sdk_client_without_a_valid_token_cannot_use_the_server(daemon, mode, token) -> None:
    async def scenario() -> None:
        http, client = session(daemon, token, mode)
        with anyio.fail_after(15):
            async with http, client:
                await client.list_tools()

    with pytest.raises(BaseException) as caught:  # the SDK wraps it in an ExceptionGroup
        await scenario()
    assert not isinstance(caught.value, (TimeoutError, KeyboardInterrupt))
    assert any(isinstance(leaf, (MCPError, httpx2.HTTPStatusError)) for leaf in leaves(caught.value)), caught.value


@pytest.mark.parametrize("path", ["/mcp", "/healthz"])
def test_a_foreign_host_header_is_rejected_with_421(daemon, path) -> None:
    headers = {"Host": "evil.example", "Authorization": f"Bearer {daemon.operator_token}",
               "Accept": "application/json, text/event-stream"}
    if path == "/mcp":
        response = httpx2.post(f"{daemon.base}{path}", headers=headers, timeout=5,
                               json={"jsonrpc": "2.0", "id": 1, "method": "tools/list", "params": {}})
    else:
        response = httpx2.get(f"{daemon.base}{path}", headers=headers, timeout=5)
    assert response.status_code == 421


def test_allowed_host_and_origin_flags_admit_exactly_the_names_given(tmp_path) -> None:
    extra = ["--allowed-host", "arm-cell.lan", "--allowed-origin", "http://console.lan:8080"]
    with http_daemon(tmp_path, speedup=20, extra_args=extra) as flagged:
        def health(host: str, origin: str | None = None) -> int:
            headers = {"Host": host} | ({"Origin": origin} if origin else {})
            return httpx2.get(f"{flagged.base}/healthz", headers=headers, timeout=5).status_code

        assert health(f"arm-cell.lan:{flagged.port}") == 200
        assert health(f"other.lan:{flagged.port}") == 421
        assert health(f"127.0.0.1:{flagged.port}", "http://console.lan:8080") == 200
        assert health(f"127.0.0.1:{flagged.port}", "http://evil.lan:8080") == 403


def test_a_new_token_under_a_revoked_tokens_name_cannot_take_over_its_session(tmp_path) -> None:
    with http_daemon(tmp_path, speedup=20) as daemon:
        old = RawSession(daemon, daemon.operator_token)
        assert "result" in old.call("get_safety_status", {})
        tokens = daemon.audit.parent / "tokens.json"
        subprocess.run([*CLI, "tokens", "revoke", str(tokens), "alice"], cwd=REPO, env=child_env(), check=True,
                       capture_output=True, timeout=60)
        successor = add_token(tokens, "operator", "alice")  # same name, different token
        old.token = successor  # present the new token on the old session
        response = old.post({"jsonrpc": "2.0", "id": 99, "method": "tools/call",
                             "params": {"name": "get_safety_status", "arguments": {}}})
        assert response.status_code == 404  # not this token's session
        fresh = RawSession(daemon, successor)  # the new token works in a session of its own
        assert "result" in fresh.call("get_safety_status", {})


# ------------------------------------------------------------------ operator
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_operator_token_plans_and_executes_with_approval(daemon, mode) -> None:
    on_elicit = approving("alice-at-the-desk")

    http, client = session(daemon, daemon.operator_token, mode, on_elicit)
    async with http, client:
        tools = {t.name for t in (await client.list_tools()).tools}
        assert {"execute_plan", "plan_to_joints", "reset_estop"} <= tools
        state = (await client.call_tool("get_robot_state", {})).structured_content
        start = state["joint_positions"]
        # joint 1 swings 1 rad from wherever it is (towards 0): above the soft step, so a human is asked
        goal = [start[0] - 1.0 if start[0] > 0 else start[0] + 1.0, *start[1:]]
        plan = await client.call_tool("plan_to_joints", {"joint_positions": goal})
        assert plan.structured_content["status"] == "needs_approval", plan.structured_content
        done = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
        assert not done.is_error, text_of(done)
        assert done.structured_content["status"] == "succeeded"
        assert done.structured_content["approval"]["operator"] == "alice-at-the-desk"
        after = (await client.call_tool("get_robot_state", {})).structured_content
        assert after["joint_positions"] == pytest.approx(goal, abs=1e-6)
    assert len(on_elicit.prompts) == 1 and "APPROVE ROBOT MOTION?" in on_elicit.prompts[0]


# ------------------------------------------------------------------ observer
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_observer_token_sees_no_motion_tools_and_cannot_execute_but_can_stop(daemon, mode) -> None:
    http, operator = session(daemon, daemon.operator_token, mode, approving("alice"))
    async with http, operator:
        plan = await operator.call_tool("plan_to_joints", {"joint_positions": HOME})
        plan_id = plan.structured_content["plan_id"]

        http2, observer = session(daemon, daemon.observer_token, mode)
        async with http2, observer:
            tools = {t.name for t in (await observer.list_tools()).tools}
            assert "execute_plan" not in tools and "plan_to_pose" not in tools and "reset_estop" not in tools
            assert {"get_robot_state", "get_safety_status", "stop_motion", "estop"} <= tools

            before = (await observer.call_tool("get_robot_state", {})).structured_content
            refused = await observer.call_tool("execute_plan", {"plan_id": plan_id})
            assert refused.is_error and "FORBIDDEN" in text_of(refused)
            after = (await observer.call_tool("get_robot_state", {})).structured_content
            assert after["joint_positions"] == before["joint_positions"]
            assert after["joint_velocities"] == [0.0] * len(HOME)
            stop = await observer.call_tool("stop_motion", {})
            assert not stop.is_error and stop.structured_content["stopped"] is True
            estop = await observer.call_tool("estop", {"reason": "observer saw a hand near the gripper"})
            assert not estop.is_error and estop.structured_content["estopped"] is True
            assert (await observer.call_tool("get_safety_status", {})).structured_content["estopped"] is True

        # the observer's e-stop holds for the operator too; the operator's approved reset releases it
        blocked = await operator.call_tool("execute_plan", {"plan_id": plan_id})
        assert blocked.is_error and ("ESTOPPED" in text_of(blocked) or "INVALIDATED_PLAN" in text_of(blocked))
        reset = await operator.call_tool("reset_estop", {})
        assert not reset.is_error, text_of(reset)
        assert reset.structured_content["estopped"] is False


@pytest.mark.anyio
async def test_healthz_without_a_token_says_only_that_the_daemon_is_up_even_while_e_stopped(daemon) -> None:
    # anyone on the network may ask: whether the arm moves or is stopped is not theirs to know
    async def scenario() -> dict[str, Any]:
        http, operator = session(daemon, daemon.operator_token, "legacy", approving("alice"))
        async with http, operator:
            assert not (await operator.call_tool("estop", {"reason": "health check test"})).is_error
            try:
                async with httpx2.AsyncClient() as anonymous:
                    response = await anonymous.get(f"{daemon.base}/healthz", timeout=5)
                assert response.status_code == 200
                return response.json()
            finally:
                assert not (await operator.call_tool("reset_estop", {})).is_error

    assert await scenario() == {"status": "ok"}


@pytest.mark.anyio
async def test_the_audit_session_is_the_one_the_sdk_bound_never_a_session_id_header_the_client_sent(daemon) -> None:
    # under 2026-07-28 the SDK ignores mcp-session-id; a client must not be able to sign its calls
    # with someone else's session id in the audit log
    http = httpx2.AsyncClient(headers={"Authorization": f"Bearer {daemon.observer_token}",
                                       "mcp-session-id": "someone-elses-session"})
    async with http, Client(streamable_http_client(daemon.url, http_client=http), mode="2026-07-28") as client:
        assert not (await client.call_tool("get_safety_status", {})).is_error
    def bobs_status_call(r: dict) -> bool:
        return r.get("principal") == "bob" and r.get("tool") == "get_safety_status"

    mine = [r for r in await wait_for_record(daemon.audit, bobs_status_call) if bobs_status_call(r)]
    assert mine and all(r["session"] != "someone-elses-session" for r in mine)


# ------------------------------------------------------------------ shutdown (keep last: it ends the daemon)
@pytest.mark.anyio
async def test_sigterm_ends_the_http_daemon_with_principals_and_a_shutdown_record_in_a_verified_audit_log(daemon) -> None:
    for token in (daemon.operator_token, daemon.observer_token):  # alice's, then bob's
        http, client = session(daemon, token, "legacy")
        async with http, client:
            assert not (await client.call_tool("get_safety_status", {})).is_error
    daemon.process.send_signal(signal.SIGTERM)
    exit_code = await anyio.to_thread.run_sync(lambda: daemon.process.wait(timeout=15))
    assert exit_code == 0, daemon.stderr_path.read_text()

    records = records_of(daemon.audit)
    principals = {r["principal"] for r in records if r["event"] == "tool_call"}
    assert {"alice", "bob"} <= principals
    assert None not in principals  # every HTTP call is attributed
    assert records[0]["event"] == "startup"
    assert records[-1]["event"] == "shutdown" and records[-1]["detail"] == "signal SIGTERM"
    with anyio.fail_after(60):
        verdict = await anyio.run_process([*CLI, "audit", "verify", str(daemon.audit)], cwd=REPO, env=child_env(), check=False)
    assert verdict.returncode == 0, verdict.stdout.decode()
    assert daemon.operator_token not in daemon.audit.read_text()
    assert daemon.observer_token not in daemon.audit.read_text()
