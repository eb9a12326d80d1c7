"""Every `tools/call` the HTTP transport or the MCP SDK refuses before any tool sees it is audited
as `request_refused`, on disk before the answer, as stdio records its refusals: a routing header
that disagrees with the body (2026-07-28, -32020), a body over 1 MiB (413, recorded by size and
digest, never in full), a body the SDK's JSON parser rejects (-32700). A call the tools saw is
recorded once, as its `tool_call`.

Found by an outside review (issue 24, item 8): these were answered but left no record.
Real daemon subprocess on 127.0.0.1, one per module.
"""

from __future__ import annotations

import hashlib
import json
import socket
import time
from collections.abc import Iterator
from typing import Any

import httpx2
import pytest
from mcp_types import CLIENT_CAPABILITIES_META_KEY, CLIENT_INFO_META_KEY, PROTOCOL_VERSION_META_KEY

from armwarden.transport.request_body import MAX_BODY_BYTES
from tests.helpers import records_of
from tests.server.http_daemon import Daemon, RawSession, http_daemon

MODERN = "2026-07-28"


@pytest.fixture(scope="module")
def daemon(tmp_path_factory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("http-refusals"), speedup=20) as running:
        yield running


def modern_call(tool: str, arguments: dict[str, Any], request_id: Any = 7) -> dict[str, Any]:
    return {"jsonrpc": "2.0", "id": request_id, "method": "tools/call", "params": {
        "name": tool, "arguments": arguments, "_meta": {
            PROTOCOL_VERSION_META_KEY: MODERN, CLIENT_CAPABILITIES_META_KEY: {},
            CLIENT_INFO_META_KEY: {"name": "raw-modern", "version": "1"}}}}


def modern_headers(daemon: Daemon, name: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {daemon.operator_token}", "Accept": "application/json, text/event-stream",
            "Content-Type": "application/json", "MCP-Protocol-Version": MODERN, "Mcp-Method": "tools/call",
            "Mcp-Name": name}


def post_modern(daemon: Daemon, body: bytes, name: str) -> httpx2.Response:
    return httpx2.post(daemon.url, content=body, headers=modern_headers(daemon, name), timeout=30)


def new_records(daemon: Daemon, before: int) -> list[dict[str, Any]]:
    return records_of(daemon.audit)[before:]


def refused(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in records if r["event"] == "request_refused"]


# ------------------------------------------------------------------ a routing header that disagrees with the body
@pytest.mark.parametrize(("tool", "arguments"), [("get_robot_state", {}), ("execute_plan", {"plan_id": "plan_x"})])
def test_a_call_whose_mcp_name_header_disagrees_with_its_body_is_refused_and_recorded(
    daemon: Daemon, tool: str, arguments: dict[str, Any]
) -> None:
    before = len(records_of(daemon.audit))

    response = post_modern(daemon, json.dumps(modern_call(tool, arguments)).encode(), name="get_safety_status")

    assert response.status_code == 400
    assert response.json()["error"]["code"] == -32020
    records = new_records(daemon, before)  # on disk before the answer
    [record] = refused(records)
    assert record["tool"] == tool and record["arguments"] == arguments
    assert record["outcome"] == "header_mismatch"
    assert "-32020" in record["detail"] and "HTTP 400" in record["detail"]
    assert not [r for r in records if r["event"] == "tool_call"]  # no tool ran


# ------------------------------------------------------------------ bodies over the limit
def test_a_declared_body_over_the_limit_is_recorded_by_its_size_not_its_content(daemon: Daemon) -> None:
    raw = RawSession(daemon, daemon.operator_token)
    before = len(records_of(daemon.audit))
    message = {"jsonrpc": "2.0", "id": 99, "method": "tools/call",
               "params": {"name": "execute_plan", "arguments": {"plan_id": "plan_x", "pad": "x" * MAX_BODY_BYTES}}}
    body = json.dumps(message).encode()

    response = raw.http.post(daemon.url, content=body, headers=raw.headers())

    assert response.status_code == 413
    [record] = refused(new_records(daemon, before))
    assert record["outcome"] == "too_large"
    assert f"declared {len(body)} bytes" in record["detail"] and "not read" in record["detail"]
    assert len(json.dumps(record)) < 2048  # a size, never the body


def test_a_streamed_body_over_the_limit_is_recorded_by_the_size_and_digest_of_what_was_read(daemon: Daemon) -> None:
    raw = RawSession(daemon, daemon.operator_token)
    before = len(records_of(daemon.audit))
    chunk = b"x" * 65536

    def body() -> Iterator[bytes]:  # no Content-Length: chunked, so the daemon must count
        yield b'{"jsonrpc": "2.0", "id": 98, "method": "tools/call", "params": {"name": "get_robot_state", "pad": "'
        for _ in range(2 * MAX_BODY_BYTES // len(chunk)):
            yield chunk

    response = raw.http.post(daemon.url, content=body(), headers=raw.headers())

    assert response.status_code == 413
    [record] = refused(new_records(daemon, before))
    assert record["outcome"] == "too_large"
    assert f"over {MAX_BODY_BYTES} bytes" in record["detail"] and "sha256 " in record["detail"]
    assert len(json.dumps(record)) < 2048


# ------------------------------------------------------------------ bodies the SDK's parser rejects
def _unparseable(kind: str, protocol: str) -> bytes:
    if kind == "nan_literal":
        return b'{"jsonrpc": "2.0", "id": 5, "method": "tools/call", "params": {"name": "plan_to_joints", ' \
               b'"arguments": {"joint_positions": [nan, 0, 0, 0, 0, 0, 0]}}}'
    # 2025-11-25: the SDK's parser stops at about 200 levels; 2026-07-28: Python's, at about 1000
    depth = 300 if protocol != MODERN else 2000
    return (b'{"jsonrpc": "2.0", "id": 6, "method": "tools/call", "params": {"name": "get_robot_state", '
            b'"arguments": {"x": ' + b"[" * depth + b"]" * depth + b"}}}")


@pytest.mark.parametrize("protocol", ["2025-11-25", MODERN])
@pytest.mark.parametrize("kind", ["nan_literal", "deep_nesting"])
def test_a_body_the_sdk_cannot_parse_is_refused_and_recorded_with_its_size_and_digest(
    daemon: Daemon, protocol: str, kind: str
) -> None:
    body = _unparseable(kind, protocol)
    if protocol == MODERN:
        before = len(records_of(daemon.audit))
        response = post_modern(daemon, body, name="get_robot_state")
    else:
        raw = RawSession(daemon, daemon.operator_token)
        before = len(records_of(daemon.audit))
        response = raw.http.post(daemon.url, content=body, headers=raw.headers())

    assert response.status_code == 400
    assert response.json()["error"]["code"] == -32700
    [record] = refused(new_records(daemon, before))
    assert record["outcome"] == "unreadable"
    assert f"{len(body)} bytes, sha256 {hashlib.sha256(body).hexdigest()}" in record["detail"]
    assert "-32700" in record["detail"]


# ------------------------------------------------------------------ what the tools saw is recorded once
def test_a_call_refused_after_the_tools_saw_it_is_recorded_once_as_its_tool_call(daemon: Daemon) -> None:
    message = modern_call("execute_plan", {"plan_id": "plan_x"})  # its record is on disk before the answer
    message["params"]["requestState"] = "forged"  # refused by the SDK inside the tool layer's audit
    before = len(records_of(daemon.audit))

    response = post_modern(daemon, json.dumps(message).encode(), name="execute_plan")

    assert response.status_code == 400
    assert response.json()["error"]["code"] == -32602
    records = new_records(daemon, before)
    assert [(r["tool"], r["outcome"]) for r in records if r["event"] == "tool_call"] == [("execute_plan", "error")]
    assert refused(records) == []


@pytest.mark.parametrize("tool", ["set_collision_thresholds", "get_robot_state"])
def test_a_call_with_malformed_input_responses_is_recorded_once_as_its_tool_call(daemon: Daemon, tool: str) -> None:
    """Found by another engineer: the SDK's pydantic ValidationError of `inputResponses` passed the
    tool layer's audit (which caught only protocol errors): answered -32602, recorded nowhere."""
    arguments = {"force_n": 20.0, "torque_nm": 10.0} if tool == "set_collision_thresholds" else {}
    message = modern_call(tool, arguments)
    message["params"]["inputResponses"] = {"approval": {"action": "maybe"}}
    before = len(records_of(daemon.audit))

    response = post_modern(daemon, json.dumps(message).encode(), name=tool)

    assert response.json()["error"]["code"] == -32602
    deadline = time.monotonic() + 30  # a read-only call's record is on disk within the commit window
    while not [r for r in new_records(daemon, before) if r["event"] == "tool_call"]:
        assert time.monotonic() < deadline, "the call left no record"
        time.sleep(0.02)
    records = new_records(daemon, before)
    [record] = [r for r in records if r["event"] == "tool_call"]
    assert (record["tool"], record["outcome"]) == (tool, "invalid")
    assert record["extra"]["code"] == "INVALID_ARGUMENTS" and "inputResponses" in record["detail"]
    assert refused(records) == []


@pytest.mark.parametrize("protocol", ["2025-11-25", MODERN])
def test_a_call_with_malformed_params_is_recorded_once(daemon: Daemon, protocol: str) -> None:
    message = modern_call("gripper_move", {}) if protocol == MODERN else {
        "jsonrpc": "2.0", "id": 8, "method": "tools/call", "params": {"name": "gripper_move"}}
    message["params"]["arguments"] = [0.04]
    body = json.dumps(message).encode()
    if protocol == MODERN:
        before = len(records_of(daemon.audit))
        response = post_modern(daemon, body, name="gripper_move")
    else:
        raw = RawSession(daemon, daemon.operator_token)
        before = len(records_of(daemon.audit))
        response = raw.http.post(daemon.url, content=body, headers=raw.headers())

    assert "-32602" in response.text
    records = new_records(daemon, before)
    assert [r["outcome"] for r in refused(records)] == ["invalid_params"]
    assert not [r for r in records if r["event"] == "tool_call"]


# ------------------------------------------------------------------ who was refused
def declare_too_large_a_body(daemon: Daemon, token: str, forwarded_for: str | None = None) -> bytes:
    """POST with a Content-Length over the limit and no body (refused before it is read), with an
    X-Forwarded-For header if given; the answer's status line."""
    forwarded = "" if forwarded_for is None else f"X-Forwarded-For: {forwarded_for}\r\n"
    with socket.create_connection(("127.0.0.1", daemon.port), timeout=30) as sock:
        sock.sendall(f"POST /mcp HTTP/1.1\r\nHost: 127.0.0.1:{daemon.port}\r\nAuthorization: Bearer {token}\r\n"
                     f"{forwarded}Content-Type: application/json\r\nContent-Length: {2 * MAX_BODY_BYTES}\r\n\r\n".encode())
        return sock.recv(4096).split(b"\r\n")[0]


def test_a_refused_request_is_recorded_with_its_authenticated_principal(daemon: Daemon) -> None:
    """Found by an outside review (issue 24, review 1, item 3): refusals carried no principal,
    while the bearer token had been checked before."""
    before = len(records_of(daemon.audit))

    status_line = declare_too_large_a_body(daemon, daemon.observer_token)

    assert b" 413 " in status_line
    [record] = refused(new_records(daemon, before))
    assert record["principal"] == "bob"


def test_a_refused_request_is_recorded_with_its_socket_peer_not_a_forwarded_for_header(daemon: Daemon) -> None:
    """Found by an outside review (issue 24, review 2, item 4): uvicorn believed X-Forwarded-For
    from loopback, so the record named whatever address the client wrote there."""
    before = len(records_of(daemon.audit))

    status_line = declare_too_large_a_body(daemon, daemon.observer_token, forwarded_for="203.0.113.9")

    assert b" 413 " in status_line
    [record] = refused(new_records(daemon, before))
    assert record["extra"]["peer"] == "127.0.0.1"


def test_a_refused_request_is_recorded_with_the_session_it_claimed(daemon: Daemon) -> None:
    raw = RawSession(daemon, daemon.observer_token)
    message = {"jsonrpc": "2.0", "id": 9, "method": "tools/call", "params": {"name": "get_robot_state", "arguments": [1]}}
    before = len(records_of(daemon.audit))

    raw.http.post(daemon.url, content=json.dumps(message).encode(), headers=raw.headers())

    [record] = refused(new_records(daemon, before))
    assert record["principal"] == "bob" and record["extra"]["session_header"] == raw.session_id
