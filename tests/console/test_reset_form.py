"""The Safety page's release form is there to be used only while an e-stop is latched: hidden
while nothing is latched (issue 31, item 7), shown once one is, for operators only."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.console.served import served_console, sign_in

pytestmark = pytest.mark.anyio

RESET_SECTION = re.compile(r'<section id="reset"( hidden)?>')


async def test_the_release_form_is_hidden_while_nothing_is_latched(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        page = await http.get("/console/safety")

    section = RESET_SECTION.search(page.text)
    assert page.status_code == 200 and "E-stop released" in page.text
    assert section is not None and section.group(1) == " hidden"


async def test_the_release_form_shows_while_an_estop_is_latched(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        page = await http.get("/console/safety")

    section = RESET_SECTION.search(page.text)
    assert "E-STOP LATCHED" in page.text
    assert section is not None and section.group(1) is None
    assert 'id="reset-form"' in page.text


async def test_the_safety_fragment_says_whether_the_estop_is_latched(tmp_path: Path) -> None:
    """The page's script shows or hides the release form from this, without a reload."""
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        released = await http.get("/console/fragment/safety")
        await served.harness.guard.emergency_stop("test", source="estop")
        latched = await http.get("/console/fragment/safety")

    assert 'id="estop-status" data-estopped="no"' in released.text
    assert 'id="estop-status" data-estopped="yes"' in latched.text
