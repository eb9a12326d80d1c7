"""The console's HTTP routes: pages, live fragments, pictures (the arm's top/side view, plan
previews, each camera's latest picture), and the four things a human can do (sign in/out, E-STOP,
release the e-stop, answer an approval request). The handlers live in `signin`, `views` and
`actions`, over the `core` they share; this module maps each route to one.

Rules every handler keeps:
- Pages and reads need a session (`sessions.py`); without one a page redirects to sign-in and a
  read answers 401. Reads are not audited (they change nothing); camera pictures come through
  the Guard as `camera_snapshot`'s do (`cameras.py`).
- Every POST but the E-STOP from loopback needs the session's CSRF token (sign-in: the login
  form's own token); a POST without it is refused (403) and audited.
- Releasing the e-stop and answering approvals need the operator role; observers see, and stop;
  agent tokens (MCP clients') cannot sign in. Nobody releases or approves here what their own
  MCP calls asked for (latched, asked to release, requested), unless `approval.allow_self_approval`.
- Everything a human does here is audited with the session's token name (`console_*` events).
- What an action did is said on the next page through a one-time flash of the session that acted
  (`SessionStore.put_flash`), never through words or codes a link could carry; without a session
  the answer is the POST's own page.
- The E-STOP button posts to the independent stop channel (`ConsoleSettings.estop_url`, its
  ``/console-estop``), which runs on its own thread, so a busy or blocked event loop cannot
  delay it; the page carries the session's E-STOP ticket for it. The console's own
  ``/estop`` route stays as the fallback (no channel configured, or the channel unreachable
  from the browser): it awaits nothing but its own small request body, calls the thread-safe
  latch-and-stop (`EStopHook`), then audits (without waiting for the disk) and answers.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from starlette.applications import Starlette
from starlette.routing import Route

from armwarden.console.actions import Actions
from armwarden.console.core import ConsoleCore, ConsoleSettings, EStopHook
from armwarden.console.sessions import SessionStore
from armwarden.console.signin import SignIn
from armwarden.console.views import Views
from armwarden.guard import Guard
from armwarden.safety.refusals import RefusalReports

__all__ = ["build_console_app"]


def console_routes(core: ConsoleCore) -> list[Route]:
    """Every route of one console, each to its handler (`signin`, `views`, `actions`)."""
    sign_in, views, actions = SignIn(core), Views(core), Actions(core)
    signed = views.signed_in
    return [
        Route("/", signed(views.state_page), methods=["GET"]),
        Route("/safety", signed(views.safety_page), methods=["GET"]),
        Route("/approvals", signed(views.approvals_page), methods=["GET"]),
        Route("/approvals/{request_id}", signed(views.approval_page), methods=["GET"]),
        Route("/approvals/{request_id}", actions.answer, methods=["POST"]),
        Route("/approvals/{request_id}/picture.png", views.plan_picture, methods=["GET"]),
        Route("/audit", signed(views.audit_page), methods=["GET"]),
        Route("/cameras", signed(views.cameras_page), methods=["GET"]),
        Route("/cameras/{camera:path}.png", views.camera_picture, methods=["GET"]),
        Route("/login", sign_in.login_page, methods=["GET"]),
        Route("/login", sign_in.login, methods=["POST"]),
        Route("/logout", sign_in.logout, methods=["POST"]),
        Route("/fragment/{name}", views.fragment, methods=["GET"]),
        Route("/api/state", views.state_json, methods=["GET"]),
        Route("/view.png", views.live_view, methods=["GET"]),
        Route("/static/{name}", views.static, methods=["GET"]),
        Route("/estop", actions.estop, methods=["POST"]),
        Route("/reset", actions.reset, methods=["POST"]),
    ]


def build_console_app(guard: Guard, sessions: SessionStore, estop: EStopHook,
                      settings: ConsoleSettings | None = None, refusals: RefusalReports | None = None,
                      clock: Callable[[], float] = time.monotonic) -> Starlette:
    """The console as an ASGI app, to be mounted at `settings.path` (beside /mcp, or alone on
    --console-port). Host/Origin checks are the mounting app's job (`transport/http.py`).
    `refusals`: the limit on records of anonymous refusals (its owner closes it). `clock`: the
    monotonic clock camera pictures age by (tests move it by hand)."""
    core = ConsoleCore(guard, sessions, estop, settings or ConsoleSettings(), refusals, clock)
    return Starlette(routes=console_routes(core))
