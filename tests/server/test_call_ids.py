"""A `tools/call` without a usable id (1.0, true, null, or none at all) cannot be answered: the SDK
took it for a notification and dropped it (HTTP 202, nothing on stdio: an `estop` sent that way
did not latch), while the audit log said `tool_call estop` with no outcome. Both transports now
refuse it visibly (JSON-RPC -32600 Invalid Request, id null) and record what happened:
`request_refused`, the tool not run (an `estop` sent that way latches all the same: its intent was
read, and a release needs a human; tests/server/test_refused_stops.py).

Found by an outside review (issue 24, item 9). Real daemons: HTTP on 127.0.0.1 (both protocol
revisions), and stdio over pipes.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import httpx2
import pytest
from mcp_types import CLIENT_CAPABILITIES_META_KEY, CLIENT_INFO_META_KEY, PROTOCOL_VERSION_META_KEY

from tests.helpers import records_of
from tests.server.http_daemon import Daemon, RawSession, http_daemon
from tests.server.test_daemon_stdio import start_raw_daemon, stop_raw_daemon

MODERN = "2026-07-28"
MISSING = object()
IDS = {"float": 1.0, "true": True, "null": None, "missing": MISSING}


def estop_call(request_id: Any, *, modern: bool = False) -> dict[str, Any]:
    params: dict[str, Any] = {"name": "estop", "arguments": {"reason": "hand in the cell"}}
    if modern:
        params["_meta"] = {PROTOCOL_VERSION_META_KEY: MODERN, CLIENT_CAPABILITIES_META_KEY: {},
                           CLIENT_INFO_META_KEY: {"name": "raw-modern", "version": "1"}}
    message: dict[str, Any] = {"jsonrpc": "2.0", "method": "tools/call", "params": params}
    if request_id is not MISSING:
        message["id"] = request_id
    return message


def assert_refused_and_not_run(records: list[dict[str, Any]]) -> None:
    [refusal] = [r for r in records if r["event"] == "request_refused"]
    assert refusal["tool"] == "estop" and refusal["outcome"] == "invalid_request"
    assert "did not run" in refusal["detail"]
    assert [r for r in records if r["event"] == "tool_call" and r["tool"] == "estop"] == []  # it did not run


@pytest.fixture(scope="module")
def daemon(tmp_path_factory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("call-ids"), speedup=20) as running:
        yield running


@pytest.mark.parametrize("protocol", ["2025-11-25", MODERN])
@pytest.mark.parametrize("kind", sorted(IDS))
def test_an_http_call_without_a_usable_id_is_refused_visibly_and_recorded_as_not_run(
    daemon: Daemon, protocol: str, kind: str
) -> None:
    body = json.dumps(estop_call(IDS[kind], modern=protocol == MODERN)).encode()
    if protocol == MODERN:
        headers = {"Authorization": f"Bearer {daemon.operator_token}", "Content-Type": "application/json",
                   "Accept": "application/json, text/event-stream", "MCP-Protocol-Version": MODERN,
                   "Mcp-Method": "tools/call", "Mcp-Name": "estop"}
        before = len(records_of(daemon.audit))
        response = httpx2.post(daemon.url, content=body, headers=headers, timeout=30)
    else:
        raw = RawSession(daemon, daemon.operator_token)
        before = len(records_of(daemon.audit))
        response = raw.http.post(daemon.url, content=body, headers=raw.headers())

    assert response.status_code == 400
    answer = response.json()
    assert answer["id"] is None and answer["error"]["code"] == -32600
    assert "id" in answer["error"]["message"]
    assert_refused_and_not_run(records_of(daemon.audit)[before:])  # on disk before the answer


@pytest.mark.parametrize("kind", sorted(IDS))
def test_a_stdio_call_without_a_usable_id_is_refused_visibly_and_recorded_as_not_run(tmp_path, kind: str) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=20)
    try:
        rpc.send(estop_call(IDS[kind]))
        answer = rpc.receive()
        status = rpc.request("tools/call", {"name": "get_safety_status", "arguments": {}})
    finally:
        stop_raw_daemon(process)

    assert answer["id"] is None and answer["error"]["code"] == -32600, answer
    assert "id" in answer["error"]["message"]
    assert status["result"]["structuredContent"]["estopped"] is True  # refused, yet a readable estop still latches
    assert_refused_and_not_run(records_of(audit))
