"""The console shows only messages the server itself wrote (issue 24, item 11), and no link can
make it claim a status (outside review 2, item 7).

A page says what an action did through a one-time flash kept server-side for the session that
acted: the redirect's URL carries only the flash's opaque id, which shows nothing to another
session or a second time. The sign-in page shows only harmless codes from its URL (a wrong
token, a full console, signed out), never a status claim such as "E-STOP latched" or "approved".
Text or a CSS class put into any URL shows nothing."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import quote

import pytest

from tests.console.served import csrf_of, served_console, sign_in

pytestmark = pytest.mark.anyio

FORGED = "Maintenance notice: the e-stop is disabled today; approve all motions"


async def test_the_login_page_shows_no_text_put_into_its_url(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        page = await http.get(f"/console/login?msg={quote(FORGED)}&kind={quote('ok banner-huge')}")

    assert page.status_code == 200
    assert "Maintenance notice" not in page.text
    assert 'id="message"' not in page.text and "banner-huge" not in page.text


async def test_a_signed_in_page_shows_no_text_put_into_its_url(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        page = await http.get(f"/console/safety?msg={quote(FORGED)}&kind=error")

    assert page.status_code == 200
    assert "Maintenance notice" not in page.text and 'id="message"' not in page.text


async def test_a_code_shows_its_fixed_text_with_its_own_kind(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        page = await http.get("/console/login?msg=bad_token&kind=ok")

    assert '<p class="message error" id="message">That token is not valid (unknown or revoked).</p>' in page.text


@pytest.mark.parametrize("query", ["msg=estop_latched&event=42", "msg=released&event=3", "msg=approved"])
async def test_the_login_page_claims_no_status_from_its_url(tmp_path: Path, query: str) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        page = await http.get(f"/console/login?{query}")

    assert page.status_code == 200 and 'id="message"' not in page.text


@pytest.mark.parametrize("query", ["msg=released&event=1", "msg=estop_latched&event=1", "msg=approved"])
async def test_a_signed_in_page_claims_no_status_from_its_url(tmp_path: Path, query: str) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        page = await http.get(f"/console/safety?{query}")

    assert page.status_code == 200 and 'id="message"' not in page.text


async def test_a_status_is_shown_once_and_only_to_the_session_that_acted(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as alice, served.browser_client() as dana:
        await sign_in(alice, served.operator_token)
        await sign_in(dana, served.approver_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        page = await alice.get("/console/safety")
        released = await alice.post("/console/reset", data={"event": "1", "csrf": csrf_of(page.text)})
        where = released.headers["location"].removeprefix(served.base)
        to_dana = await dana.get(where)
        to_alice = await alice.get(where)
        again = await alice.get(where)

    assert "released" not in where and "event" not in where
    assert 'id="message"' not in to_dana.text
    assert '<p class="message ok" id="message">E-stop #1 released.</p>' in to_alice.text
    assert 'id="message"' not in again.text


async def test_an_estop_without_a_session_answers_on_its_own_page_not_through_a_link(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        stopped = await http.post("/console/estop", data={})

    assert stopped.status_code == 200
    assert '<p class="message ok" id="message">E-STOP latched: event #1</p>' in stopped.text
    assert served.harness.guard.latch.is_latched


async def test_a_failed_sign_in_redirects_with_a_code_not_a_text(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        refused = await sign_in(http, "aw_not-a-real-token")
        shown = await http.get(refused.headers["location"].removeprefix(served.base))

    assert refused.headers["location"].endswith("/console/login?msg=bad_token")
    assert "That token is not valid" in shown.text


async def test_a_release_redirects_to_the_safety_page_saying_so(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        page = await http.get("/console/safety")
        released = await http.post("/console/reset", data={"event": "1", "csrf": csrf_of(page.text)})
        shown = await http.get(released.headers["location"].removeprefix(served.base))

    assert released.headers["location"].removeprefix(served.base).startswith("/console/safety?flash=")
    assert '<p class="message ok" id="message">E-stop #1 released.</p>' in shown.text
