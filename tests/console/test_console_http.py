"""The operator console over real HTTP (uvicorn on 127.0.0.1), mounted beside /mcp: sign-in,
CSRF, roles, E-STOP, reset, approvals shown, pictures, audit page. Browser tests: test_browser.py."""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

from armwarden.console import ConsoleSettings
from tests.console.served import csrf_of, served_console, sign_in
from tests.helpers import records_of
from tests.server.harness import answer, plan_down, policy_with

pytestmark = pytest.mark.anyio

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------ sign-in
async def test_operator_signs_in_and_sees_the_live_state(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        signed = await sign_in(http, served.operator_token)
        page = await http.get("/console/")

    assert signed.status_code == 303
    assert page.status_code == 200
    assert "fr3_joint1" in page.text and 'id="tcp"' in page.text
    assert "alice (operator)" in page.text


async def test_session_cookie_is_httponly_and_samesite_strict(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        signed = await sign_in(http, served.operator_token)

    cookie = next(v for k, v in signed.headers.multi_items() if k == "set-cookie" and v.startswith("armwarden_console="))
    assert "HttpOnly" in cookie
    assert "SameSite=strict" in cookie or "SameSite=Strict" in cookie


async def test_wrong_token_is_refused_and_audited(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        signed = await sign_in(http, "aw_not-a-real-token")
        page = await http.get("/console/")

    assert "armwarden_console=" not in signed.headers.get("set-cookie", "")
    assert page.status_code == 303 and page.headers["location"].endswith("/console/login")
    refused = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_sign_in"]
    assert refused and refused[-1]["outcome"] == "refused"


async def test_sign_in_without_the_forms_csrf_token_is_refused(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await http.get("/console/login")
        signed = await http.post("/console/login", data={"token": served.operator_token})

    assert signed.status_code == 403
    assert "armwarden_console=" not in signed.headers.get("set-cookie", "")


async def test_pages_need_sign_in(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        page = await http.get("/console/audit")
        state = await http.get("/console/api/state")
        picture = await http.get("/console/view.png")

    assert page.status_code == 303
    assert state.status_code == 401
    assert picture.status_code == 401


async def test_the_mcp_endpoint_still_needs_its_bearer_token(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        mcp = await http.post("/mcp", json={"jsonrpc": "2.0", "id": 1, "method": "ping"})

    assert mcp.status_code == 401


# ------------------------------------------------------------------ CSRF and roles
async def test_post_without_csrf_is_refused_and_audited(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        reset = await http.post("/console/reset", data={"event": "1"})

    assert reset.status_code == 403
    assert served.harness.guard.latch.is_latched
    refused = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_refused"]
    assert refused and refused[-1]["principal"] == "alice" and "CSRF" in refused[-1]["detail"]


async def test_cross_site_post_is_refused_by_the_origin_check(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        stop = await http.post("/console/estop", headers={"Origin": "http://evil.example"})

    assert stop.status_code == 403
    assert not served.harness.guard.latch.is_latched


async def test_observer_sees_but_cannot_release_the_estop(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        await served.harness.guard.emergency_stop("test", source="estop")
        page = await http.get("/console/safety")
        reset = await http.post("/console/reset", data={"event": "1", "csrf": csrf_of(page.text)})

    assert page.status_code == 200 and "E-STOP LATCHED" in page.text
    assert 'id="reset-form"' not in page.text
    assert reset.status_code == 403
    assert served.harness.guard.latch.is_latched


# ------------------------------------------------------------------ E-STOP and reset
async def test_estop_from_loopback_works_without_sign_in_and_is_audited(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        stop = await http.post("/console/estop", headers={"Accept": "application/json"})

    assert stop.status_code == 200 and stop.json()["estopped"] is True
    assert served.harness.guard.latch.is_latched
    served.harness.audit.flush()
    estops = [r for r in records_of(served.harness.audit_path) if r["event"] == "estop"]
    assert estops and estops[-1]["principal"].startswith("console (not signed in")


async def test_estop_without_sign_in_is_refused_when_the_settings_say_so(tmp_path: Path) -> None:
    settings = ConsoleSettings(estop_from_loopback_without_sign_in=False)
    async with served_console(tmp_path, settings=settings) as served, served.browser_client() as http:
        stop = await http.post("/console/estop", headers={"Accept": "application/json"})

    assert stop.status_code == 401
    assert not served.harness.guard.latch.is_latched


async def test_signed_in_estop_is_audited_with_the_token_name(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        page = await http.get("/console/")
        stop = await http.post("/console/estop", data={"csrf": csrf_of(page.text)})

    assert stop.status_code == 303
    assert served.harness.guard.latch.is_latched
    served.harness.audit.flush()
    estops = [r for r in records_of(served.harness.audit_path) if r["event"] == "estop"]
    assert estops[-1]["principal"] == "bob"


async def test_a_signed_in_estop_with_a_stale_csrf_token_still_stops_and_says_so(tmp_path: Path) -> None:
    """A tab opened before a newer sign-in in another tab carries an old CSRF token: its E-STOP
    must not be refused for it."""
    settings = ConsoleSettings(estop_from_loopback_without_sign_in=False)  # not the unsigned rule at work
    async with served_console(tmp_path, settings=settings) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        old_tab = await http.get("/console/")
        await sign_in(http, served.observer_token)  # the other tab: a new session replaces the cookie
        stop = await http.post("/console/estop", data={"csrf": csrf_of(old_tab.text)},
                               headers={"Accept": "application/json"})

    assert stop.status_code == 200 and stop.json()["estopped"] is True
    assert served.harness.guard.latch.is_latched
    served.harness.audit.flush()
    estops = [r for r in records_of(served.harness.audit_path) if r["event"] == "estop"]
    assert estops[-1]["principal"] == "bob (stale CSRF token)"


async def test_reset_needs_the_number_of_the_latched_event(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        await served.harness.guard.emergency_stop("first", source="estop")
        await served.harness.guard.emergency_stop("second", source="estop")
        page = await http.get("/console/safety")
        csrf = csrf_of(page.text)
        wrong = await http.post("/console/reset", data={"event": "1", "csrf": csrf})
        wrong_shown = await http.get(wrong.headers["location"].removeprefix(served.base))
        still_latched = served.harness.guard.latch.is_latched
        right = await http.post("/console/reset", data={"event": "2", "csrf": csrf})
        right_shown = await http.get(right.headers["location"].removeprefix(served.base))

    assert "event #2" in page.text
    assert wrong.status_code == 303 and '<p class="message error" id="message">Release refused: nothing' in wrong_shown.text
    assert still_latched
    assert right.status_code == 303 and '<p class="message ok" id="message">E-stop #2 released.</p>' in right_shown.text
    assert not served.harness.guard.latch.is_latched
    resets = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_reset_estop"]
    assert [r["outcome"] for r in resets] == ["refused", "released"]
    assert resets[-1]["operator"] == "alice"


# ------------------------------------------------------------------ approvals, pictures, audit
async def test_pending_approval_is_shown_with_its_picture(tmp_path: Path) -> None:
    asked = anyio.Event()

    async def wait_for_console(context, params):  # the client's prompt stays open while we look
        asked.set()
        await anyio.sleep(30)
        return await answer("decline")(context, params)

    policy = policy_with(**{"approval.mode": "always"})
    async with served_console(tmp_path, policy) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        async with served.mcp_client(elicitation=wait_for_console) as client, anyio.create_task_group() as group:
            plan = await plan_down(client, 0.40, status="needs_approval")
            group.start_soon(client.call_tool, "execute_plan", {"plan_id": plan["plan_id"]})
            with anyio.fail_after(10):
                await asked.wait()
            listing = await http.get("/console/approvals")
            request_id = served.harness.guard.approvals.live(served.harness.guard.latch.generation)[0].request_id
            page = await http.get(f"/console/approvals/{request_id}")
            picture = await http.get(f"/console/approvals/{request_id}/picture.png")
            group.cancel_scope.cancel()

    assert plan["plan_id"] in listing.text
    assert "APPROVE ROBOT MOTION?" in page.text
    assert 'id="client-only"' in page.text  # channel form: answered in the MCP client
    assert picture.status_code == 200 and picture.content.startswith(PNG_MAGIC)


async def test_live_view_is_a_png(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        picture = await http.get("/console/view.png")

    assert picture.status_code == 200 and picture.content.startswith(PNG_MAGIC)


async def test_state_feed_reports_joints_against_limits(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        state = (await http.get("/console/api/state")).json()

    joints = state["robot"]["joints"]
    assert len(joints) == 7
    assert all(j["min"] <= j["position"] <= j["max"] for j in joints)
    assert state["safety"]["estopped"] is False


async def test_audit_page_shows_the_tail_and_an_intact_chain(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        page = await http.get("/console/audit")

    assert "audit verify: intact" in page.text
    assert "console_sign_in" in page.text


async def test_pages_carry_a_strict_content_security_policy(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        page = await http.get("/console/login")

    channel_origin = served.channel.console_url.removesuffix("/console-estop")
    assert "script-src 'self'" in page.headers["content-security-policy"]
    assert f"form-action 'self' {channel_origin};" in page.headers["content-security-policy"]
    # the stop channel (another origin) must see this page's origin, not "null"; never a path
    assert page.headers["referrer-policy"] == "strict-origin-when-cross-origin"
