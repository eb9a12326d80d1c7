"""The operator console in a real headless browser (Debian chromium + selenium): sign in, see a
pending approval with its picture, approve (execute_plan completes) or decline (refused, nothing
moved), E-STOP an executing motion, and the refusals (replayed link, wrong token, no CSRF)."""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import anyio
import anyio.from_thread
import mcp_types as types
import pytest

from armwarden.console.core import ConsoleSettings
from armwarden.policy import Policy
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from tests.console.browser import chromium
from tests.console.served import ServedConsole, served_console
from tests.helpers import REPO, records_of, text_of
from tests.server.harness import HOME_TCP_X, policy_with

URL_POLICY = {"approval.mode": "always", "approval.channel": "url"}
#: the approval flow that ends in a motion: the fake, the console, the SDK client and chromium's
#: driver share this test process, whose wrench samples were seen 0.18-0.51 s apart beside two CPU
#: hogs; the longest wrench timeout a policy may set, as the harness gives in-process cells
#: (tests/server/harness.py). Wrench staleness has tests of its own.
MOVING_URL_POLICY = {**URL_POLICY, "force.wrench_timeout_s": MAX_WRENCH_TIMEOUT_S}
#: set to a directory to save the console screenshots (docs/ uses them)
SCREENSHOTS_ENV = "ARMWARDEN_CONSOLE_SCREENSHOTS"
WAIT_S = 15


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Any]:
    with chromium(tmp_path / "profile") as driver:
        yield driver


class Session:
    """A console served in a portal thread, an MCP client in it, and the links it was sent."""

    def __init__(self, portal: anyio.from_thread.BlockingPortal, served: ServedConsole) -> None:
        self.portal, self.served = portal, served
        self.links: list[str] = []
        self.link_arrived = threading.Event()

    async def elicitation(self, context: Any, params: Any) -> types.ElicitResult:
        self.links.append(params.url)
        self.link_arrived.set()
        return types.ElicitResult(action="accept")  # the human opened the link; the console decides

    def plan_and_execute(self, z: float = 0.40) -> Future:
        """Plan a move down to `z` and call execute_plan in the portal; the call's future."""
        async def run() -> Any:
            async with self.served.mcp_client(elicitation=self.elicitation) as client:
                planned = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": z}})
                assert not planned.is_error, text_of(planned)
                return await client.call_tool("execute_plan", {"plan_id": planned.structured_content["plan_id"]})

        return self.portal.start_task_soon(run)

    def wait_for_link(self) -> str:
        assert self.link_arrived.wait(WAIT_S), "no URL-mode elicitation arrived"
        return self.links[-1]


@contextlib.contextmanager
def console(tmp_path: Path, policy: Policy | None = None, settings: ConsoleSettings | None = None,
            **fake: Any) -> Iterator[Session]:
    with anyio.from_thread.start_blocking_portal() as portal, \
            portal.wrap_async_context_manager(served_console(tmp_path, policy, settings, **fake)) as served:
        yield Session(portal, served)


def sign_in(browser: Any, served: ServedConsole, token: str) -> None:
    from selenium.webdriver.common.by import By

    browser.get(served.console + "/login")
    browser.find_element(By.ID, "token").send_keys(token)
    browser.find_element(By.ID, "sign-in").click()
    wait_for(browser, lambda b: b.find_elements(By.ID, "who") or b.find_elements(By.ID, "message"))


def wait_for(browser: Any, condition: Any) -> Any:
    """Until `condition` holds. An element found and then replaced by the page before it was read
    (a stale reference: the console re-renders after an action) is one more try, not a failure."""
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(browser, WAIT_S, ignored_exceptions=(StaleElementReferenceException,)).until(condition)


def click_and_load(browser: Any, element_id: str) -> None:
    """Click a submit button and wait until the page it leads to has replaced this one."""
    from selenium.webdriver.common.by import By

    button = browser.find_element(By.ID, element_id)
    button.click()
    wait_for(browser, lambda _: detached(button))


def detached(element: Any) -> bool:
    """Whether `element`'s document has been replaced. Like Selenium's `staleness_of`, and also
    true on the answer Chrome gives while it tears the old document down ("Node with given id
    does not belong to the document"), which `staleness_of` lets escape as an error."""
    from selenium.common.exceptions import StaleElementReferenceException, WebDriverException

    try:
        element.is_enabled()
    except StaleElementReferenceException:
        return True
    except WebDriverException as exc:
        if "does not belong to the document" in str(exc):
            return True
        raise
    return False


def screenshot(browser: Any, name: str) -> None:
    directory = os.environ.get(SCREENSHOTS_ENV)
    if directory:
        browser.save_screenshot(str(Path(directory) / name))


# ------------------------------------------------------------------ sign-in
def test_sign_in_shows_the_live_state(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    with console(tmp_path) as session:
        sign_in(browser, session.served, session.served.operator_token)
        wait_for(browser, ec.presence_of_element_located((By.ID, "joints")))
        picture_loaded = wait_for(browser, lambda b: b.execute_script(
            "const i = document.getElementById('live-view'); return i.complete && i.naturalWidth > 0;"))
        screenshot(browser, "console-state.png")
        who = browser.find_element(By.ID, "who").text

    assert who == "alice (operator)"
    assert picture_loaded


def test_a_wrong_token_is_refused(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path) as session:
        sign_in(browser, session.served, "aw_not-a-real-token")
        message = browser.find_element(By.ID, "message").text
        browser.get(session.served.console + "/")
        still_login = browser.find_elements(By.ID, "login-form")

    assert "not valid" in message
    assert still_login


# ------------------------------------------------------------------ cameras
#: the pixels of the picture of one camera on the page, as a data URL (None until it has loaded)
PICTURE_PIXELS = """
    const img = document.querySelector('[data-camera="' + arguments[0] + '"] img');
    if (!img || img.hidden || !img.complete || !img.naturalWidth) { return null; }
    const canvas = document.createElement('canvas');
    canvas.width = img.naturalWidth; canvas.height = img.naturalHeight;
    canvas.getContext('2d').drawImage(img, 0, 0);
    return canvas.toDataURL();"""


#: how many pictures of one camera the page has shown (its load handler counts them)
PICTURE_LOADS = """return document.querySelector('[data-camera="' + arguments[0] + '"] img').dataset.loads || "0";"""


def test_the_camera_view_shows_each_camera_and_keeps_it_current(tmp_path: Path, browser: Any) -> None:
    """The fake's cameras number their frames: the picture on the page changes while it is open."""
    with console(tmp_path) as session:
        sign_in(browser, session.served, session.served.observer_token)
        browser.get(session.served.console + "/cameras")
        first = {name: wait_for(browser, lambda b, n=name: b.execute_script(PICTURE_PIXELS, n)) for name in ("wrist", "scene")}
        newer = wait_for(browser, lambda b: (b.execute_script(PICTURE_PIXELS, "scene") or first["scene"]) != first["scene"])
        loads = wait_for(browser, lambda b: int(b.execute_script(PICTURE_LOADS, "scene")) >= 2)

    assert all(pixels.startswith("data:image/png") for pixels in first.values())
    assert newer
    assert loads  # the page counted each new picture it showed


def test_a_failing_camera_shows_its_error_in_the_page(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    from armwarden.core.errors import BackendError

    async def broken(camera: str) -> None:
        raise BackendError(f"{camera}: lens cap on")

    with console(tmp_path) as session:
        cameras = session.served.harness.fake.cell.cameras
        assert cameras is not None
        cameras.snapshot = broken  # type: ignore[method-assign]
        sign_in(browser, session.served, session.served.operator_token)
        browser.get(session.served.console + "/cameras")
        error = browser.find_element(By.CSS_SELECTOR, '[data-camera="wrist"] .camera-error')
        wait_for(browser, lambda _: error.is_displayed())
        text = error.text
        picture_shown = browser.find_element(By.CSS_SELECTOR, '[data-camera="wrist"] img').is_displayed()
        nav = browser.find_element(By.ID, "nav-cameras").text

    assert "wrist: lens cap on" in text and "BACKEND_ERROR" in text
    assert not picture_shown
    assert nav == "Cameras"


def test_the_camera_view_shows_mujocos_rendered_cameras(tmp_path: Path, browser: Any) -> None:
    """The screenshot in docs/console.md: `armwarden serve --backend mujoco` with the README's
    scene (its box on the table), as a process of its own, and its cameras in the console."""
    pytest.importorskip("mujoco")
    from selenium.webdriver.common.by import By

    from tests.server.http_daemon import http_daemon

    with http_daemon(tmp_path, speedup=1.0, backend="mujoco", config=REPO / "examples" / "mujoco_scene.yaml") as daemon:
        browser.set_window_size(1400, 940)
        browser.get(daemon.base + "/console/login")
        browser.find_element(By.ID, "token").send_keys(daemon.operator_token)
        click_and_load(browser, "sign-in")
        browser.get(daemon.base + "/console/cameras")
        first = {name: wait_for(browser, lambda b, n=name: b.execute_script(PICTURE_PIXELS, n)) for name in ("scene", "wrist")}
        screenshot(browser, "console-cameras.png")

    assert all(pixels.startswith("data:image/png") for pixels in first.values())


# ------------------------------------------------------------------ approvals
def test_approve_in_the_browser_and_execute_plan_completes(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path, policy_with(**MOVING_URL_POLICY)) as session:
        sign_in(browser, session.served, session.served.approver_token)
        call = session.plan_and_execute()
        browser.get(session.wait_for_link())
        picture_loaded = wait_for(browser, lambda b: b.execute_script(
            "const i = document.getElementById('plan-picture'); return i.complete && i.naturalWidth > 0;"))
        screenshot(browser, "console-approval.png")
        browser.find_element(By.ID, "approve").click()
        result = call.result(timeout=WAIT_S)
        moved = "execute" in session.served.harness.actuations

    assert picture_loaded
    assert not result.is_error, text_of(result)
    assert result.structured_content["status"] == "succeeded"
    assert result.structured_content["approval"]["operator"] == "dana"
    assert moved


def test_decline_in_the_browser_refuses_and_nothing_moves(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path, policy_with(**URL_POLICY)) as session:
        sign_in(browser, session.served, session.served.approver_token)
        call = session.plan_and_execute()
        browser.get(session.wait_for_link())
        browser.find_element(By.ID, "decline").click()
        result = call.result(timeout=WAIT_S)
        actuations = list(session.served.harness.actuations)

    assert result.is_error and "declined" in text_of(result)
    assert actuations == []


def test_a_replayed_approval_link_is_refused(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path, policy_with(**URL_POLICY)) as session:
        sign_in(browser, session.served, session.served.approver_token)
        call = session.plan_and_execute()
        link = session.wait_for_link()
        browser.get(link)
        first_tab = browser.current_window_handle
        browser.switch_to.new_window("tab")
        browser.get(link)  # the same link open twice
        browser.find_element(By.ID, "approve").click()
        call.result(timeout=WAIT_S)
        browser.switch_to.window(first_tab)
        click_and_load(browser, "approve")  # the stale tab answers again
        message = browser.find_element(By.ID, "message").text

    assert "already approved" in message


def test_an_observer_sees_the_request_but_cannot_approve(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path, policy_with(**URL_POLICY)) as session:
        sign_in(browser, session.served, session.served.observer_token)
        call = session.plan_and_execute()
        browser.get(session.wait_for_link())
        buttons = browser.find_elements(By.ID, "approve")
        note = browser.find_element(By.ID, "observer-note").text
        session.served.harness.guard.approvals.withdraw(session.served.harness.guard.approvals.live(
            session.served.harness.guard.latch.generation)[0].plan_id, "test over")
        result = call.result(timeout=WAIT_S)

    assert buttons == []
    assert "observer" in note
    assert result.is_error


# ------------------------------------------------------------------ E-STOP, reset, CSRF
def test_estop_stops_an_executing_motion_and_the_latch_shows(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    with console(tmp_path, speedup=0.05) as session:  # a slow motion: about 20 s of travel
        sign_in(browser, session.served, session.served.observer_token)
        call = session.plan_and_execute(z=0.30)
        guard = session.served.harness.guard
        wait_for(browser, lambda b: guard.motion_status().progress > 0)
        action = browser.find_element(By.ID, "estop-form").get_attribute("action")
        browser.find_element(By.ID, "estop-button").click()
        answer = wait_for(browser, ec.presence_of_element_located((By.ID, "estop-answer"))).text
        latched = wait_for(browser, lambda b: "E-STOP LATCHED" in b.find_element(By.ID, "estop-status").text)
        result = call.result(timeout=WAIT_S)
        channel_url = session.served.channel.console_url
        audit_path = session.served.harness.audit_path

    assert action == channel_url  # the independent stop channel, not the event loop's console route
    assert answer.startswith("E-STOP latched through the stop channel: event #")  # read back, not assumed
    assert latched
    assert result.structured_content["status"] == "aborted"
    estop = [r for r in records_of(audit_path) if r["event"] == "estop"][-1]
    assert estop["principal"] == "bob" and estop["extra"]["peer"].startswith("console via stop channel")


def test_an_estop_the_channel_refuses_is_shown_as_failed_never_as_sent(tmp_path: Path, browser: Any) -> None:
    """The channel's answer to the page is opaque (no-cors): a page not signed in, on a console
    that needs sign-in for a stop, is refused by the channel and must say so, not "sent"."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    with console(tmp_path, settings=ConsoleSettings(estop_from_loopback_without_sign_in=False)) as session:
        browser.get(session.served.console + "/login")
        action = browser.find_element(By.ID, "estop-form").get_attribute("action")
        browser.find_element(By.ID, "estop-button").click()
        answer = wait_for(browser, ec.presence_of_element_located((By.ID, "estop-answer"))).text
        latched = session.served.harness.guard.latch.is_latched

    assert action == session.served.channel.console_url
    assert answer.startswith("Stop channel not confirmed; E-STOP FAILED:"), answer
    assert "sign-in" in answer
    assert not latched


def test_the_estop_of_a_page_whose_session_ended_still_stops(tmp_path: Path, browser: Any) -> None:
    """With --console-estop-needs-sign-in, a page left open while its session expired (here: its
    session expires by the store's clock) must still stop, and must not say E-STOP FAILED."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    from armwarden.console.sessions import SESSION_TTL_S
    from tests.helpers import FakeClock

    clock = FakeClock(0.0)
    settings = ConsoleSettings(estop_from_loopback_without_sign_in=False)
    with console(tmp_path, settings=settings, session_clock=clock) as session:
        sign_in(browser, session.served, session.served.observer_token)
        wait_for(browser, ec.presence_of_element_located((By.ID, "who")))
        clock.advance(SESSION_TTL_S)  # the page stays open; its session is over
        browser.find_element(By.ID, "estop-button").click()
        answer = wait_for(browser, ec.presence_of_element_located((By.ID, "estop-answer"))).text
        latched = session.served.harness.guard.latch.is_latched
        audit_path = session.served.harness.audit_path
        session.served.harness.audit.flush()

    assert "E-STOP latched" in answer and "FAILED" not in answer, answer
    assert latched
    estops = [r for r in records_of(audit_path) if r["event"] == "estop"]
    assert estops and all(r["principal"] == "bob (session ended)" for r in estops)


def test_estop_without_script_shows_the_channels_answer_page(tmp_path: Path, browser: Any) -> None:
    """A browser running no script posts the form itself and is shown the channel's answer."""
    from selenium.webdriver.common.by import By

    with console(tmp_path) as session:
        browser.execute_cdp_cmd("Emulation.setScriptExecutionDisabled", {"value": True})
        browser.get(session.served.console + "/login")
        click_and_load(browser, "estop-button")
        answer = browser.find_element(By.ID, "estop-result").text
        back = browser.find_element(By.TAG_NAME, "a").get_attribute("href")
        guard = session.served.harness.guard

    assert answer.startswith("E-STOP latched: event #")
    assert back == session.served.console + "/safety"
    assert guard.latch.is_latched


def test_reset_from_the_browser_needs_the_event_number(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path) as session:
        guard = session.served.harness.guard
        session.portal.call(guard.emergency_stop, "test", "estop")
        sign_in(browser, session.served, session.served.operator_token)
        browser.get(session.served.console + "/safety")
        browser.find_element(By.ID, "reset-event").send_keys("7")
        click_and_load(browser, "reset-button")
        refused = browser.find_element(By.ID, "message").text
        browser.find_element(By.ID, "reset-event").send_keys("1")
        click_and_load(browser, "reset-button")
        released = browser.find_element(By.ID, "message").text

    assert "refused" in refused
    assert "E-stop #1 released" in released
    assert not guard.latch.is_latched


def test_the_release_form_shows_only_while_an_estop_is_latched(tmp_path: Path, browser: Any) -> None:
    """The Safety page left open: the form appears when an e-stop latches, and goes once released."""
    from selenium.webdriver.common.by import By

    with console(tmp_path) as session:
        guard = session.served.harness.guard
        sign_in(browser, session.served, session.served.operator_token)
        browser.get(session.served.console + "/safety")
        hidden_at_first = not browser.find_element(By.ID, "reset-form").is_displayed()
        session.portal.call(guard.emergency_stop, "test", "estop")
        shown = wait_for(browser, lambda b: b.find_element(By.ID, "reset-form").is_displayed())
        browser.find_element(By.ID, "reset-event").send_keys("1")
        click_and_load(browser, "reset-button")
        released = browser.find_element(By.ID, "message").text
        hidden_after = not browser.find_element(By.ID, "reset-form").is_displayed()

    assert hidden_at_first
    assert shown
    assert "E-stop #1 released" in released
    assert hidden_after


def test_the_latched_banner_keeps_the_header_on_one_row(tmp_path: Path, browser: Any) -> None:
    """At a typical desktop width, the E-STOP's answer sits below the header's items; it does not
    push the navigation or the sign-out onto a row of their own."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    with console(tmp_path) as session:
        browser.set_window_size(1280, 900)
        sign_in(browser, session.served, session.served.operator_token)
        browser.find_element(By.ID, "estop-button").click()
        wait_for(browser, ec.presence_of_element_located((By.ID, "estop-answer")))
        wait_for(browser, lambda b: "E-STOP LATCHED" in b.find_element(By.ID, "estop-status").text)
        boxes = browser.execute_script("""
            const box = (s) => { const r = document.querySelector(s).getBoundingClientRect();
                                 return {top: r.top, bottom: r.bottom, middle: (r.top + r.bottom) / 2}; };
            return {estop: box('#estop-form'), title: box('header h1'), nav: box('header nav'),
                    signout: box('header .signout'), banner: box('#estop-answer')};""")

    middles = [boxes[k]["middle"] for k in ("estop", "title", "nav", "signout")]
    assert max(middles) - min(middles) <= 2, boxes  # one row
    assert boxes["banner"]["top"] >= boxes["estop"]["bottom"], boxes  # below it, not in it


def test_a_post_without_the_csrf_token_is_refused(tmp_path: Path, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    with console(tmp_path) as session:
        guard = session.served.harness.guard
        session.portal.call(guard.emergency_stop, "test", "estop")
        sign_in(browser, session.served, session.served.operator_token)
        browser.get(session.served.console + "/safety")
        browser.execute_script("document.querySelector('#reset-form input[name=csrf]').remove();")
        browser.find_element(By.ID, "reset-event").send_keys("1")
        click_and_load(browser, "reset-button")
        message = browser.find_element(By.ID, "message").text

    assert "CSRF" in message
    assert guard.latch.is_latched
