"""`GET /metrics` on a real `armwarden serve --transport http` (127.0.0.1, bearer tokens), driven by
the SDK's client and scraped with httpx2, parsed with prometheus_client's own parser.

Counts are compared before and after what a test does, so tests do not depend on each other's
calls; the e-stop test latches its daemon, so it has one of its own.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx2
import pytest
from prometheus_client.parser import text_string_to_metric_families

from tests.helpers import HOME, records_of, stop_process
from tests.server.http_daemon import Daemon, http_daemon, session

Samples = dict[tuple[str, frozenset[tuple[str, str]]], float]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("metrics-daemon"), speedup=20) as running:
        yield running


def scrape(daemon: Daemon, token: str | None) -> httpx2.Response:
    headers = {} if token is None else {"Authorization": f"Bearer {token}"}
    return httpx2.get(f"{daemon.base}/metrics", headers=headers, timeout=10)


def samples(daemon: Daemon) -> Samples:
    """Every sample of a scrape with the observer's token (the least role), by name and labels."""
    response = scrape(daemon, daemon.observer_token)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("text/plain")
    return {(sample.name, frozenset(sample.labels.items())): sample.value
            for family in text_string_to_metric_families(response.text) for sample in family.samples}


def value(scraped: Samples, name: str, **labels: str) -> float:
    return scraped.get((name, frozenset(labels.items())), 0.0)


def total(scraped: Samples, name: str, **labels: str) -> float:
    """The sum over every series of `name` whose labels include `labels`."""
    return sum(v for (n, have), v in scraped.items() if n == name and frozenset(labels.items()) <= have)


async def call(daemon: Daemon, tool: str, arguments: dict) -> None:
    http, client = session(daemon, daemon.operator_token, "legacy")
    async with http, client:
        await client.call_tool(tool, arguments)


@pytest.mark.anyio
async def test_a_refused_call_is_counted_under_its_tool_and_code(daemon) -> None:
    before = samples(daemon)
    await call(daemon, "execute_plan", {"plan_id": "no-such-plan"})
    after = samples(daemon)
    refusals = ("armwarden_refusals_total", {"tool": "execute_plan", "code": "UNKNOWN_PLAN"})
    assert value(after, refusals[0], **refusals[1]) == value(before, refusals[0], **refusals[1]) + 1
    calls = ("armwarden_tool_calls_total", {"tool": "execute_plan", "status": "refused"})
    assert value(after, calls[0], **calls[1]) == value(before, calls[0], **calls[1]) + 1


@pytest.mark.anyio
async def test_a_call_and_a_plan_land_in_their_latency_histograms(daemon) -> None:
    before = samples(daemon)
    await call(daemon, "plan_to_joints", {"joint_positions": HOME})
    after = samples(daemon)
    count = "armwarden_tool_call_duration_seconds_count"
    assert value(after, count, tool="plan_to_joints") == value(before, count, tool="plan_to_joints") + 1
    assert value(after, "armwarden_tool_call_duration_seconds_sum", tool="plan_to_joints") > 0
    plans = "armwarden_plan_duration_seconds_count"  # one series per plan status
    assert total(after, plans, tool="plan_to_joints") == total(before, plans, tool="plan_to_joints") + 1
    # the call's audit record (and the scrape before it) went through the audit writer
    assert value(after, "armwarden_audit_write_duration_seconds_count", durability="now") > 0


def test_the_fake_backends_servo_loop_is_timed(daemon) -> None:
    first = samples(daemon)
    assert value(first, "armwarden_servo_period_seconds", backend="fake") > 0
    ticks = value(first, "armwarden_servo_ticks_total", backend="fake")
    assert ticks > 0
    assert ("armwarden_servo_deadline_misses_total", frozenset({("backend", "fake")})) in first


@pytest.mark.parametrize("token", [None, "aw_not-a-real-token"], ids=["no_token", "wrong_token"])
def test_a_scrape_without_a_valid_token_is_401(daemon, token) -> None:
    response = scrape(daemon, token)
    assert response.status_code == 401
    assert response.headers["www-authenticate"].startswith("Bearer")
    assert "armwarden_" not in response.text


def test_a_scrape_from_a_foreign_host_name_is_refused_before_its_token_is_looked_at(daemon) -> None:
    response = httpx2.get(f"{daemon.base}/metrics", timeout=10,
                          headers={"Authorization": f"Bearer {daemon.observer_token}", "Host": "evil.example:80"})
    assert response.status_code == 421


def test_scrapes_served_are_not_audited_and_refused_ones_go_through_the_refusal_limiter(tmp_path: Path) -> None:
    """60 refused scrapes: fewer records than refusals (a flood is thinned), yet every one is
    accounted for once the daemon has shut down — a record of its own, or counted in a later
    record (`not_reported_since_last`) or in a `refusals_left_out` record. Scrapes with a token
    write nothing."""
    refused = 60
    with http_daemon(tmp_path, speedup=20) as running:
        for _ in range(5):
            assert scrape(running, running.observer_token).status_code == 200
        for _ in range(refused):
            assert scrape(running, "aw_not-a-real-token").status_code == 401
        stop_process(running.process, 10)
        records = records_of(running.audit)
    assert records[-1]["event"] == "shutdown"
    own = [r for r in records if r["event"] == "request_refused" and "/metrics" in (r["detail"] or "")]
    assert 0 < len(own) < refused
    counted = sum((r["extra"] or {}).get("not_reported_since_last", 0) for r in own)
    left_out = sum(r["extra"]["count"] for r in records
                   if r["event"] == "refusals_left_out" and r["extra"]["door"] == "transport")
    assert len(own) + counted + left_out == refused
    # the five scrapes served left nothing (whatever else a loaded machine makes the daemon record)
    assert not [r for r in records if r["event"] in ("tool_call", "request_refused") and "/metrics" not in (r["detail"] or "")]


@pytest.mark.anyio
async def test_a_latched_estop_is_counted_by_its_source(tmp_path: Path) -> None:
    with http_daemon(tmp_path, speedup=20) as running:
        before = samples(running)
        assert value(before, "armwarden_estop_latched") == 0
        await call(running, "estop", {"reason": "metrics test"})
        after = samples(running)
    assert value(after, "armwarden_estops_latched_total", source="estop") == \
        value(before, "armwarden_estops_latched_total", source="estop") + 1
    assert value(after, "armwarden_estop_latched") == 1
    assert value(after, "armwarden_tool_calls_total", tool="estop", status="ok") == 1
