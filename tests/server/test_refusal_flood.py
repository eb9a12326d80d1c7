"""A flood of requests refused before the tools see them costs at most a burst of audit records
and then one per principal (or host) and second, the rest counted into the next record; a
refusal whose stop request acted (a hold, a latch) is always recorded.

Found by an outside review (issue 24, review 1, item 4): 1000 POSTs that only declared a body
over the limit wrote 1000 fsynced `request_refused` records, 463 KB in 2.4 s.
Real daemon subprocess on 127.0.0.1.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from typing import Any

import pytest

from armwarden.daemon import REFUSAL_RECORDS_BURST
from armwarden.safety.refusals import REPORT_INTERVAL_S
from tests.helpers import records_of
from tests.server.http_daemon import Daemon, RawSession, http_daemon
from tests.server.test_http_refusals_audited import declare_too_large_a_body

FLOOD = 3 * REFUSAL_RECORDS_BURST


@pytest.fixture
def daemon(tmp_path) -> Iterator[Daemon]:
    with http_daemon(tmp_path, speedup=20) as running:
        yield running


def refusals_of(daemon: Daemon, principal: str, since: int = 0) -> list[dict[str, Any]]:
    return [r for r in records_of(daemon.audit)[since:] if r["event"] == "request_refused" and r["principal"] == principal]


def test_a_flood_of_refused_requests_is_recorded_as_a_burst_then_once_per_second(daemon: Daemon) -> None:
    started = time.monotonic()
    for _ in range(FLOOD):
        assert b" 413 " in declare_too_large_a_body(daemon, daemon.observer_token)
    elapsed = time.monotonic() - started

    recorded = refusals_of(daemon, "bob")
    assert REFUSAL_RECORDS_BURST <= len(recorded) <= REFUSAL_RECORDS_BURST + math.ceil(elapsed / REPORT_INTERVAL_S) + 1
    assert len(recorded) < FLOOD
    # the ones left out are counted into bob's next record
    deadline = time.monotonic() + 30
    while not (counted := [r for r in refusals_of(daemon, "bob") if r["extra"] and
                           r["extra"].get("not_reported_since_last", 0) > 0]):
        assert time.monotonic() < deadline, "no record counted the refusals left out"
        declare_too_large_a_body(daemon, daemon.observer_token)
    assert sum(r["extra"]["not_reported_since_last"] for r in counted) >= FLOOD - len(recorded) - 1


def test_refusals_whose_stop_requests_acted_are_all_recorded_during_a_flood(daemon: Daemon) -> None:
    for _ in range(FLOOD):
        declare_too_large_a_body(daemon, daemon.observer_token)
    raw = RawSession(daemon, daemon.observer_token)
    before = len(records_of(daemon.audit))

    for tool in ("stop_motion", "estop", "stop_motion", "estop", "stop_motion"):
        message = {"jsonrpc": "2.0", "id": None, "method": "tools/call", "params": {"name": tool, "arguments": {}}}
        assert raw.http.post(daemon.url, content=json.dumps(message).encode(), headers=raw.headers()).status_code == 400

    recorded = refusals_of(daemon, "bob", before)
    assert [r["tool"] for r in recorded] == ["stop_motion", "estop", "stop_motion", "estop", "stop_motion"]
    assert [r["extra"]["stops"] for r in recorded] == [["stop_motion"], ["estop"], ["stop_motion"], ["estop"],
                                                       ["stop_motion"]]
