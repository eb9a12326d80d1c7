"""Console sessions over real HTTP (issue 24, item 6): sign-ins by one token never push out
another token's session, a full console refuses a new sign-in with a clear message instead, and
the E-STOP of a page whose session has ended (expired, pushed out, signed out) still stops,
through the stop channel and through the console's own route, audited with the token's name.
A revoked token's page does not (with --console-estop-needs-sign-in)."""

from __future__ import annotations

from pathlib import Path

import anyio
import httpx2
import pytest

from armwarden.console import ConsoleSettings
from armwarden.console.sessions import MAX_SESSIONS, MAX_SESSIONS_PER_PRINCIPAL, SESSION_TTL_S, Session, SignInRefused
from armwarden.transport.tokens import TokenStore
from tests.console.served import ServedConsole, csrf_of, served_console, sign_in
from tests.console.test_console_estop_channel import press_estop, ticket_of
from tests.helpers import FakeClock, records_of

pytestmark = pytest.mark.anyio

NEEDS_SIGN_IN = ConsoleSettings(estop_from_loopback_without_sign_in=False)


async def test_sign_ins_of_one_token_never_sign_out_another_token(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as bob, served.browser_client() as alice:
        await sign_in(bob, served.observer_token)
        for _ in range(MAX_SESSIONS + 6):
            alice.cookies.clear()
            await sign_in(alice, served.operator_token)
        page = await bob.get("/console/")
        latest = await alice.get("/console/")

    assert page.status_code == 200 and "bob (observer)" in page.text
    assert latest.status_code == 200


async def test_a_tokens_own_oldest_session_makes_room_for_its_new_sign_in(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served:
        tabs = [served.browser_client() for _ in range(MAX_SESSIONS_PER_PRINCIPAL + 1)]
        try:
            for tab in tabs:
                await sign_in(tab, served.operator_token)
            pages = [(await tab.get("/console/")).status_code for tab in tabs]
        finally:
            for tab in tabs:
                await tab.aclose()

    assert pages == [303] + [200] * MAX_SESSIONS_PER_PRINCIPAL


async def test_a_full_console_refuses_a_new_sign_in_with_a_clear_message(tmp_path: Path) -> None:
    tokens = tmp_path / "tokens.json"
    async with served_console(tmp_path) as served, served.browser_client() as http:
        assert served.sessions is not None
        extra = [TokenStore.add(tokens, "operator", name=f"watcher{i}") for i in range(MAX_SESSIONS // MAX_SESSIONS_PER_PRINCIPAL)]
        for token in extra:
            for _ in range(MAX_SESSIONS_PER_PRINCIPAL):
                assert isinstance(served.sessions.sign_in(token), Session)
        refused = await sign_in(http, served.observer_token)
        shown = await http.get(refused.headers["location"].removeprefix(served.base))

    assert refused.status_code == 303 and "armwarden_console=" not in refused.headers.get("set-cookie", "")
    assert "sessions" in shown.text and "sign out" in shown.text
    records = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_sign_in"]
    assert records[-1]["outcome"] == "refused" and records[-1]["extra"]["reason"] == "full"


async def test_observers_cannot_take_the_room_kept_for_operators(tmp_path: Path) -> None:
    """Outside review 2, item 6: observer tokens signing in over and over filled the whole console
    and locked the operators out; observers now hold only part of it."""
    tokens = tmp_path / "tokens.json"
    async with served_console(tmp_path) as served, served.browser_client() as http:
        assert served.sessions is not None
        watchers = [TokenStore.add(tokens, "observer", name=f"watcher{i}") for i in range(MAX_SESSIONS // MAX_SESSIONS_PER_PRINCIPAL)]
        observers = [served.sessions.sign_in(token) for token in watchers for _ in range(MAX_SESSIONS_PER_PRINCIPAL)]
        signed = await sign_in(http, served.approver_token)
        page = await http.get("/console/")

    assert signed.headers["location"].endswith("/console/")
    assert page.status_code == 200 and "dana (operator)" in page.text
    assert any(isinstance(answer, SignInRefused) and answer.reason == "full" for answer in observers)


async def _expired_page(served: ServedConsole, http: httpx2.AsyncClient, clock: FakeClock) -> str:
    """Sign in as bob, keep the page, and let its session expire."""
    await sign_in(http, served.observer_token)
    page = (await http.get("/console/")).text
    clock.advance(SESSION_TTL_S)
    assert (await http.get("/console/api/state")).status_code == 401  # the session is over
    return page


async def test_an_expired_sessions_page_stops_through_the_channel(tmp_path: Path) -> None:
    clock = FakeClock(0.0)
    async with served_console(tmp_path, settings=NEEDS_SIGN_IN, session_clock=clock) as served, \
            served.browser_client() as http:
        page = await _expired_page(served, http, clock)
        status, answer = await anyio.to_thread.run_sync(press_estop, served, ticket_of(page))
        latched = served.harness.guard.latch.is_latched
        served.harness.audit.flush()

    assert status == 200 and "E-STOP latched" in answer, answer
    assert latched
    estops = [r for r in records_of(served.harness.audit_path) if r["event"] == "estop"]
    assert estops[-1]["principal"] == "bob (session ended)"


async def test_an_expired_sessions_page_stops_through_the_consoles_own_route(tmp_path: Path) -> None:
    clock = FakeClock(0.0)
    async with served_console(tmp_path, settings=NEEDS_SIGN_IN, session_clock=clock) as served, \
            served.browser_client() as http:
        page = await _expired_page(served, http, clock)
        stop = await http.post("/console/estop", data={"csrf": csrf_of(page), "ticket": ticket_of(page)},
                               headers={"Accept": "application/json"})
        latched = served.harness.guard.latch.is_latched
        served.harness.audit.flush()

    assert stop.status_code == 200 and stop.json()["estopped"] is True
    assert latched
    estops = [r for r in records_of(served.harness.audit_path) if r["event"] == "estop"]
    assert estops[-1]["principal"] == "bob (session ended)"


async def test_a_page_pushed_out_by_its_own_tokens_sign_ins_still_stops(tmp_path: Path) -> None:
    async with served_console(tmp_path, settings=NEEDS_SIGN_IN) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        page = (await http.get("/console/")).text
        for _ in range(MAX_SESSIONS_PER_PRINCIPAL):
            http.cookies.clear()
            await sign_in(http, served.observer_token)
        status, answer = await anyio.to_thread.run_sync(press_estop, served, ticket_of(page))

    assert status == 200 and "E-STOP latched" in answer, answer
    assert served.harness.guard.latch.is_latched


async def test_a_revoked_tokens_page_does_not_stop_when_the_console_needs_sign_in(tmp_path: Path) -> None:
    async with served_console(tmp_path, settings=NEEDS_SIGN_IN) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        page = (await http.get("/console/")).text
        assert served.tokens_path is not None
        TokenStore.revoke(served.tokens_path, "bob")
        status, _ = await anyio.to_thread.run_sync(press_estop, served, ticket_of(page))
        stop = await http.post("/console/estop", data={"csrf": csrf_of(page), "ticket": ticket_of(page)},
                               headers={"Accept": "application/json"})

    assert status == 401 and stop.status_code == 401
    assert not served.harness.guard.latch.is_latched
