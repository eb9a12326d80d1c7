"""A readable stop request that is refused before its tool runs still does what its tool means
(docs/threat-model.md: "a clumsy stop still latches"): an `estop` latches a new e-stop event,
recorded with why; a `stop_motion` holds the arm (as it always did, on receipt) and latches
nothing. Whoever refuses it — the transport (no usable id), the MCP SDK before the tools see it
(a routing header that disagrees, an unacceptable Accept, an unknown session), or the SDK after
(a forged request state) — on both protocol revisions over HTTP, and on stdio.

Found by an outside review (issue 24, review 1, item 1): such an `estop` held the arm but did not
latch, so the next plan ran without a human. Real daemons: HTTP on 127.0.0.1, stdio over pipes.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx2
import pytest
from mcp_types import CLIENT_CAPABILITIES_META_KEY, CLIENT_INFO_META_KEY, PROTOCOL_VERSION_META_KEY

from tests.helpers import records_of
from tests.server.harness import HOME_TCP_X
from tests.server.http_daemon import Daemon, RawSession, http_daemon
from tests.server.test_daemon_stdio import start_raw_daemon, stop_raw_daemon

MODERN = "2026-07-28"
REASON = "hand in the cell"


def legacy_call(tool: str, request_id: Any = 41) -> dict[str, Any]:
    return {"jsonrpc": "2.0", "id": request_id, "method": "tools/call",
            "params": {"name": tool, "arguments": {"reason": REASON} if tool == "estop" else {}}}


def modern_call(tool: str, request_id: Any = 42) -> dict[str, Any]:
    message = legacy_call(tool, request_id)
    message["params"]["_meta"] = {PROTOCOL_VERSION_META_KEY: MODERN, CLIENT_CAPABILITIES_META_KEY: {},
                                  CLIENT_INFO_META_KEY: {"name": "raw-modern", "version": "1"}}
    return message


def modern_headers(daemon: Daemon, name: str = "estop") -> dict[str, str]:
    return {"Authorization": f"Bearer {daemon.operator_token}", "Accept": "application/json, text/event-stream",
            "Content-Type": "application/json", "MCP-Protocol-Version": MODERN, "Mcp-Method": "tools/call",
            "Mcp-Name": name}


Send = Callable[[Daemon, str], httpx2.Response]


def legacy(change: Callable[[dict[str, Any], dict[str, str]], None]) -> Send:
    def send(daemon: Daemon, tool: str) -> httpx2.Response:
        raw = RawSession(daemon, daemon.operator_token)
        message, headers = legacy_call(tool), raw.headers()
        change(message, headers)
        return raw.http.post(daemon.url, content=json.dumps(message).encode(), headers=headers)
    return send


def modern(change: Callable[[dict[str, Any], dict[str, str]], None]) -> Send:
    def send(daemon: Daemon, tool: str) -> httpx2.Response:
        message, headers = modern_call(tool), modern_headers(daemon, tool)
        change(message, headers)
        return httpx2.post(daemon.url, content=json.dumps(message).encode(), headers=headers, timeout=30)
    return send


def _set(where: str, key: str, value: Any) -> Callable[[dict[str, Any], dict[str, str]], None]:
    def change(message: dict[str, Any], headers: dict[str, str]) -> None:
        target: dict[str, Any] = headers if where == "headers" else message if where == "message" else message["params"]
        target[key] = value
    return change


#: each a way to have a readable stop request refused before its tool runs
REFUSALS: dict[str, Send] = {
    "legacy: id 1.0 (the transport)": legacy(_set("message", "id", 1.0)),
    "legacy: unknown session (SDK, 404)": legacy(_set("headers", "mcp-session-id", "no-such-session")),
    "legacy: Accept without event streams (SDK, 406)": legacy(_set("headers", "Accept", "application/json")),
    f"{MODERN}: Mcp-Name names another tool (SDK, -32020)": modern(_set("headers", "Mcp-Name", "get_safety_status")),
    f"{MODERN}: unsupported protocol version (SDK)": modern(_set("headers", "MCP-Protocol-Version", "1999-01-01")),
    f"{MODERN}: forged request state (SDK, after the tools saw it)": modern(_set("params", "requestState", "forged")),
}


@pytest.fixture(scope="module")
def daemon(tmp_path_factory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("refused-stops"), speedup=20) as running:
        yield running


def safety_status(daemon: Daemon) -> dict[str, Any]:
    return RawSession(daemon, daemon.observer_token).call("get_safety_status", {})["result"]["structuredContent"]


def newest_event(daemon: Daemon) -> int:
    status = safety_status(daemon)
    return (status["estop_event"] or {}).get("number", 0) if status["estopped"] else 0


@pytest.mark.parametrize("refusal", sorted(REFUSALS))
def test_a_refused_estop_request_latches_a_new_estop_event_and_records_why(daemon: Daemon, refusal: str) -> None:
    before_event, before = newest_event(daemon), len(records_of(daemon.audit))

    response = REFUSALS[refusal](daemon, "estop")

    assert response.status_code >= 400, response.text
    status = safety_status(daemon)
    assert status["estopped"] is True
    event = status["estop_event"]
    assert event["number"] > before_event and event["source"] == "estop"  # its reason is shown as unverified
    assert event["reason"] == REASON
    [latch] = [r for r in records_of(daemon.audit)[before:] if r["event"] == "estop" and r["tool"] == "estop"]
    assert latch["outcome"] == "latched" and latch["extra"]["estop_event"] == event["number"]
    assert latch["principal"] == "alice" and "not run" in latch["detail"]


@pytest.mark.parametrize("refusal", sorted(REFUSALS))
def test_a_refused_stop_motion_request_holds_the_arm_and_latches_nothing(daemon: Daemon, refusal: str) -> None:
    before_event, before = newest_event(daemon), len(records_of(daemon.audit))

    response = REFUSALS[refusal](daemon, "stop_motion")

    assert response.status_code >= 400, response.text
    assert newest_event(daemon) == before_event
    records = records_of(daemon.audit)[before:]
    assert [(r["tool"], r["outcome"]) for r in records if r["event"] == "stop_on_receipt"] == [("stop_motion", "stopped")]
    assert [r for r in records if r["event"] == "estop"] == []


def test_after_a_refused_estop_request_nothing_moves_without_a_human(tmp_path) -> None:
    with http_daemon(tmp_path, speedup=20) as running:
        response = REFUSALS["legacy: id 1.0 (the transport)"](running, "estop")
        assert response.status_code == 400 and response.json()["error"]["code"] == -32600

        raw = RawSession(running, running.operator_token)
        plan = raw.call("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.40}})["result"]

    assert plan["isError"] is True and "ESTOPPED" in plan["content"][0]["text"]
    [refusal] = [r for r in records_of(running.audit) if r["event"] == "request_refused"]
    assert refusal["tool"] == "estop" and refusal["extra"]["estop_event"] == 1
    assert "e-stop #1 latched" in refusal["detail"]


@pytest.mark.parametrize("message", [
    {"jsonrpc": "2.0", "method": "tools/call", "params": {"name": "estop", "arguments": {"reason": REASON}}},
    {"jsonrpc": "1.0", "id": 3, "method": "tools/call", "params": {"name": "estop", "arguments": {"reason": REASON}}},
], ids=["no id", "not JSON-RPC 2.0"])
def test_a_stdio_estop_request_refused_as_unanswerable_or_unreadable_latches(tmp_path, message: dict[str, Any]) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=20)
    try:
        rpc.send(message)
        refusal = rpc.receive()
        status = rpc.request("tools/call", {"name": "get_safety_status", "arguments": {}})["result"]["structuredContent"]
    finally:
        stop_raw_daemon(process)

    assert refusal["id"] is None and refusal["error"]["code"] == -32600, refusal
    assert status["estopped"] is True and status["estop_event"]["reason"] == REASON
    [latch] = [r for r in records_of(audit) if r["event"] == "estop" and r["tool"] == "estop"]
    assert latch["outcome"] == "latched" and latch["extra"]["estop_event"] == status["estop_event"]["number"]


# ------------------------------------------------------------------ batches: every element is screened
def post_batch(daemon: Daemon, protocol: str, elements: list[dict[str, Any]]) -> httpx2.Response:
    body = json.dumps(elements).encode()
    if protocol == MODERN:
        return httpx2.post(daemon.url, content=body, headers=modern_headers(daemon), timeout=30)
    raw = RawSession(daemon, daemon.operator_token)
    return raw.http.post(daemon.url, content=body, headers=raw.headers())


@pytest.mark.parametrize("protocol", ["2025-11-25", MODERN])
def test_a_batch_is_refused_and_each_stop_request_in_it_acts(daemon: Daemon, protocol: str) -> None:
    make = modern_call if protocol == MODERN else legacy_call
    batch = [make("get_robot_state", 51), make("stop_motion", 52), make("estop", 53), make("estop", 54)]
    before_event, before = newest_event(daemon), len(records_of(daemon.audit))

    response = post_batch(daemon, protocol, batch)

    assert response.status_code == 400 and response.json()["error"]["code"] == -32600
    event = safety_status(daemon)["estop_event"]
    assert event["number"] == before_event + 1 and event["reason"] == REASON  # one latch per batch
    records = records_of(daemon.audit)[before:]
    assert sorted(r["tool"] for r in records if r["event"] == "stop_on_receipt") == ["estop", "stop_motion"]
    [refusal] = [r for r in records if r["event"] == "request_refused"]
    assert refusal["tool"] == "estop" and refusal["extra"]["estop_event"] == event["number"]
    assert refusal["extra"]["batch"] == ["get_robot_state", "stop_motion", "estop", "estop"]
    assert [r for r in records if r["event"] == "tool_call" and r["principal"] == "alice"] == []  # none of them ran


@pytest.mark.parametrize("protocol", ["2025-11-25", MODERN])
def test_a_stop_motion_in_a_batch_holds_and_latches_nothing(daemon: Daemon, protocol: str) -> None:
    make = modern_call if protocol == MODERN else legacy_call
    before_event, before = newest_event(daemon), len(records_of(daemon.audit))

    response = post_batch(daemon, protocol, [make("stop_motion", 61)])

    assert response.status_code == 400
    assert newest_event(daemon) == before_event
    records = records_of(daemon.audit)[before:]
    assert [(r["tool"], r["outcome"]) for r in records if r["event"] == "stop_on_receipt"] == [("stop_motion", "stopped")]
    [refusal] = [r for r in records if r["event"] == "request_refused"]
    assert refusal["tool"] == "stop_motion" and "held the robot" in refusal["detail"]


def test_an_estop_in_a_batch_stops_a_running_motion(tmp_path) -> None:
    with http_daemon(tmp_path, speedup=0.25) as slow:
        raw = RawSession(slow, slow.operator_token)
        plan = raw.call("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.35}})["result"]["structuredContent"]
        assert plan["status"] == "ok", plan
        motion = raw.open_call("execute_plan", {"plan_id": plan["plan_id"]})
        deadline = time.monotonic() + 30
        while not raw.call("get_motion_status", {})["result"]["structuredContent"]["executing"]:
            assert time.monotonic() < deadline, "the motion did not start"

        response = post_batch(slow, "2025-11-25", [legacy_call("estop", 900)])

        assert response.status_code == 400
        ended = motion.wait_for(lambda event: event.get("id") is not None and ("result" in event or "error" in event))
        status = safety_status(slow)
    assert ended["result"]["structuredContent"]["status"] != "succeeded", ended
    assert status["estopped"] is True and status["estop_event"]["reason"] == REASON
    [refusal] = [r for r in records_of(slow.audit) if r["event"] == "request_refused"]
    assert refusal["tool"] == "estop" and refusal["extra"]["estop_event"] == status["estop_event"]["number"]


def test_a_stdio_batch_with_an_estop_latches(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=20)
    try:
        rpc.send_line(json.dumps([legacy_call("estop", 5)]).encode())
        refusal = rpc.receive()
        status = rpc.request("tools/call", {"name": "get_safety_status", "arguments": {}})["result"]["structuredContent"]
    finally:
        stop_raw_daemon(process)

    assert refusal["id"] is None and refusal["error"]["code"] == -32600, refusal
    assert status["estopped"] is True and status["estop_event"]["reason"] == REASON
    [record] = [r for r in records_of(audit) if r["event"] == "request_refused"]
    assert record["tool"] == "estop" and record["extra"]["batch"] == ["estop"]
