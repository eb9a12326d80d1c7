"""Refused console requests of nobody in particular (failed sign-ins, POSTs without a session)
are audited at most once per host and second; the records left out are counted in the next one
(issue 24, item 7: 300 of them in half a second wrote 300 fsynced records). Refusals of a
signed-in session are each recorded: they name who did it."""

from __future__ import annotations

import time
from pathlib import Path

import anyio
import httpx2
import pytest

from armwarden.safety.refusals import REPORT_INTERVAL_S
from tests.console.served import ServedConsole, csrf_of, served_console, sign_in
from tests.helpers import records_of

pytestmark = pytest.mark.anyio

FLOOD = 60


def unauthenticated(served: ServedConsole) -> list[dict]:
    return [r for r in records_of(served.harness.audit_path)
            if r["event"] in ("console_sign_in", "console_refused") and r["outcome"] == "refused" and r["principal"] is None]


async def flood(http: httpx2.AsyncClient, served: ServedConsole, count: int) -> float:
    """`count` refused requests, alternating a wrong token and a POST without a session; seconds taken."""
    started = time.monotonic()
    for i in range(count):
        if i % 2:
            answer = await sign_in(http, "aw_not-a-real-token")
            assert answer.status_code == 303
        else:
            answer = await http.post("/console/reset", data={"event": "1"})
            assert answer.status_code == 401
    return time.monotonic() - started


async def after_the_interval() -> None:
    """Long enough that the next refusal of this host is reported."""
    await anyio.sleep(REPORT_INTERVAL_S * 1.2)


def left_out(served: ServedConsole) -> list[dict]:
    """The console's counts of refusals reported on their own (`refusals_left_out`)."""
    return [r for r in records_of(served.harness.audit_path)
            if r["event"] == "refusals_left_out" and r["extra"]["door"] == "console"]


def accounted(served: ServedConsole) -> int:
    """Unauthenticated refusals the log accounts for: each record, the ones it says were left out
    before it, and the counts reported on their own."""
    records = unauthenticated(served)
    return len(records) + sum(r["extra"]["not_reported_since_last"] for r in records) + \
        sum(r["extra"]["count"] for r in left_out(served))


async def wait_until_accounted(served: ServedConsole, count: int) -> None:
    """The log accounts for `count` refusals (a quiet host's count is reported on a timer)."""
    with anyio.fail_after(30):
        while True:
            if accounted(served) >= count:
                return
            await anyio.sleep(0.05)


async def test_a_flood_of_unauthenticated_refusals_is_recorded_once_per_second_and_counted(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        took_s = await flood(http, served, FLOOD)
        await after_the_interval()
        await flood(http, served, 1)
        await wait_until_accounted(served, FLOOD + 1)
        records = unauthenticated(served)

        assert len(records) <= took_s / REPORT_INTERVAL_S + 2  # one per started second, and the last one
        assert accounted(served) == FLOOD + 1
        assert records[0]["extra"]["not_reported_since_last"] == 0


async def test_a_burst_of_unauthenticated_refusals_then_silence_is_counted_in_full(tmp_path: Path) -> None:
    """Found by an outside review (issue 24, review 2, item 5a): the count of a burst that then
    stopped was never written (only with that host's next refusal, if any)."""
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await flood(http, served, FLOOD)

        await wait_until_accounted(served, FLOOD)

        counted = left_out(served)
        assert counted and all(r["extra"]["source"] == "127.0.0.1" and r["principal"] is None for r in counted)


async def test_refusals_of_a_signed_in_session_are_each_recorded(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        for _ in range(5):
            refused = await http.post("/console/reset", data={"event": "1"})  # no CSRF token
            assert refused.status_code == 403

    records = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_refused"]
    assert [r["principal"] for r in records] == ["alice"] * 5


async def test_a_forwarded_for_header_neither_makes_a_new_host_of_each_refusal_nor_names_the_peer(tmp_path: Path) -> None:
    """Found by an outside review (issue 24, review 2, item 4): uvicorn believed X-Forwarded-For
    from loopback, so one client wrote a record per forged address, each naming that address."""
    async with served_console(tmp_path) as served, served.browser_client() as http:
        csrf = csrf_of((await http.get("/console/login")).text)
        started = time.monotonic()
        for i in range(FLOOD):
            answer = await http.post("/console/login", data={"token": "aw_not-a-real-token", "csrf": csrf},
                                     headers={"X-Forwarded-For": f"10.0.{i // 256}.{i % 256}"})
            assert answer.status_code == 303
        took_s = time.monotonic() - started
        records = unauthenticated(served)

    assert {r["extra"]["peer"] for r in records} == {"127.0.0.1"}
    assert len(records) <= took_s / REPORT_INTERVAL_S + 2
