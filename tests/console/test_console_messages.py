"""The console shows only messages the server itself wrote (issue 24, item 11): a redirect after
an action carries a code (and at most an event number), the page maps it to a fixed text and a
fixed kind; text or a CSS class put into the URL by anyone else shows nothing."""

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


async def test_the_number_in_a_message_must_be_a_number(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        number = await http.get("/console/safety?msg=released&event=7")
        text = await http.get(f"/console/safety?msg=released&event={quote('7 by the safety officer')}")

    assert "E-stop #7 released." in number.text
    assert 'id="message"' not in text.text and "safety officer" not in text.text


async def test_a_failed_sign_in_redirects_with_a_code_not_a_text(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        refused = await sign_in(http, "aw_not-a-real-token")
        shown = await http.get(refused.headers["location"].removeprefix(served.base))

    assert refused.headers["location"].endswith("/console/login?msg=bad_token")
    assert "That token is not valid" in shown.text


async def test_a_release_redirects_with_its_code_and_event_number(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        page = await http.get("/console/safety")
        released = await http.post("/console/reset", data={"event": "1", "csrf": csrf_of(page.text)})
        shown = await http.get(released.headers["location"].removeprefix(served.base))

    assert released.headers["location"].endswith("/console/safety?msg=released&event=1")
    assert '<p class="message ok" id="message">E-stop #1 released.</p>' in shown.text
