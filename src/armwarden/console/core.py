"""What every console handler shares: the console's settings, its Guard, sessions and feeds, and
the helpers that look up a session, audit, refuse, and answer with a page or a redirect.

Apart from the handlers so that the rules every handler keeps (routes.py's docstring) are
carried out in one place: a refusal is always audited the same way, a page always carries the
same headers and flash.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response

from armwarden.console.cameras import CameraFeed
from armwarden.console.feed import StateFeed
from armwarden.console.pages import SECURITY_HEADERS, MessageKind, message_text, page_headers, render
from armwarden.console.sessions import COOKIE, LOGIN_COOKIE, Session, SessionStore, same_secret
from armwarden.guard import Guard
from armwarden.safety.refusals import RefusalReports, left_out_recorder
from armwarden.transport.http import CONSOLE_PATH, is_loopback_host

__all__ = ["CONSOLE_PATH", "ConsoleCore", "ConsoleSettings", "EStopHook", "is_loopback_peer"]

#: latch the e-stop and stop the arm from any thread: (reason, principal, peer) -> e-stop event number
EStopHook = Callable[[str, str, str], int]


@dataclass(frozen=True)
class ConsoleSettings:
    """How the console behaves; the daemon builds it from the command line and the policy."""

    #: the E-STOP button works without sign-in for requests from this machine
    estop_from_loopback_without_sign_in: bool = True
    #: approval requests may be answered here (`approval.channel` url or both); `form`: shown only
    answer_approvals: bool = False
    #: the path the console is mounted at (links and the cookie's Path)
    path: str = CONSOLE_PATH
    #: where the E-STOP button posts: the stop channel's ``/console-estop`` (None: this console's
    #: own ``/estop`` route, which runs on the event loop)
    estop_url: str | None = None


def _origin_of(url: str | None) -> str | None:
    """``scheme://host:port`` of `url`, for the pages' Content-Security-Policy."""
    if url is None:
        return None
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    return f"{parts.scheme}://{parts.netloc}"


def is_loopback_peer(request: Request) -> bool:
    client = request.client
    return client is not None and is_loopback_host(client.host)


class ConsoleCore:
    """The state and helpers of one console, bound to one Guard; the handlers (`signin`, `views`,
    `actions`) each hold it."""

    def __init__(self, guard: Guard, sessions: SessionStore, estop: EStopHook, settings: ConsoleSettings,
                 refusals: RefusalReports | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.guard = guard
        self.sessions = sessions
        self.estop_hook = estop
        self.settings = settings
        self.feed = StateFeed(guard)
        self.cameras = CameraFeed(guard, clock)
        self.headers = page_headers(_origin_of(settings.estop_url))
        #: records of refusals of nobody in particular, per host (one per second, the rest counted
        #: and reported as `refusals_left_out`); the daemon passes its own to close at shutdown
        self.anonymous_refusals = refusals if refusals is not None else RefusalReports(
            on_left_out=left_out_recorder(guard.audit, "console"))

    # ------------------------------------------------------------------ helpers
    @property
    def base(self) -> str:
        return self.settings.path

    def session_of(self, request: Request) -> Session | None:
        return self.sessions.lookup(request.cookies.get(COOKIE))

    async def audit(self, event: str, session: Session | None, outcome: str, detail: str, *,
                    principal: str | None = None, **extra: Any) -> None:
        """An audit record of the console (`principal`: who, when there is no session)."""
        audit = self.guard.audit
        if audit is None:
            return
        name = principal if session is None else session.name
        await audit.append_async(event, principal=name, outcome=outcome, operator=None if session is None else session.name,
                                 detail=detail, extra={"via": "console", **extra})

    async def audit_anonymous_refusal(self, request: Request, event: str, detail: str, **extra: Any) -> None:
        """A refusal of nobody in particular (no session, no valid token): at most one record per
        host and second, the ones left out counted into the next (`safety.refusals`), so a flood
        of them cannot buy a disk flush each."""
        host = request.client.host if request.client else "?"
        left_out = self.anonymous_refusals.admit(host)
        if left_out is not None:
            await self.audit(event, None, "refused", detail, peer=host, not_reported_since_last=left_out, **extra)

    async def refuse(self, request: Request, session: Session | None, status: int, why: str) -> Response:
        """A refused console action: audited (without a session, as `audit_anonymous_refusal`),
        answered with the reason."""
        detail = f"{request.method} {request.url.path}: {why}"
        if session is None:
            await self.audit_anonymous_refusal(request, "console_refused", detail)
        else:
            await self.audit("console_refused", session, "refused", detail,
                             peer=request.client.host if request.client else None)
        if "application/json" in request.headers.get("accept", ""):
            return JSONResponse({"error": why}, status_code=status, headers=SECURITY_HEADERS)
        return render("login.html" if session is None else "safety.html", status_code=status, base=self.base,
                      headers=self.headers, estop_url=self.settings.estop_url,
                      session=session, message=why, message_kind="error", login_csrf="",
                      sign_in_enabled=self.sessions.enabled, safety=self.feed.safety())

    async def form_of(self, request: Request) -> dict[str, str]:
        form = await request.form()
        return {k: v for k, v in form.items() if isinstance(v, str)}

    def csrf_ok(self, request: Request, form: dict[str, str], session: Session) -> bool:
        return same_secret(form.get("csrf") or request.headers.get("x-csrf-token"), session.csrf)

    def page(self, template: str, request: Request, session: Session, **context: Any) -> Response:
        """A signed-in page, saying what the session's flash named in its URL says (once)."""
        flash = self.sessions.take_flash(session, request.query_params.get("flash"))
        message, kind = (message_text(*flash) if flash is not None else None) or (None, "ok")
        return render(template, base=self.base, session=session, message=message, message_kind=kind,
                      headers=self.headers, estop_url=self.settings.estop_url, **context)

    def back(self, session: Session, where: str, code: str, event: int | None = None) -> RedirectResponse:
        """Redirect to `where`, whose page then says `MESSAGES[code]` to `session` only, once (the
        URL carries the flash's opaque id only)."""
        return RedirectResponse(f"{self.base}{where}?flash={self.sessions.put_flash(session, code, event)}",
                                status_code=303)

    def login_form(self, message: str | None, kind: MessageKind, status_code: int = 200) -> Response:
        """The sign-in page with its own CSRF cookie, saying `message` (None: nothing)."""
        import secrets

        token = secrets.token_urlsafe(24)
        response = render("login.html", status_code=status_code, base=self.base, login_csrf=token,
                          sign_in_enabled=self.sessions.enabled, headers=self.headers,
                          estop_url=self.settings.estop_url, message=message, message_kind=kind)
        response.set_cookie(LOGIN_COOKIE, token, httponly=True, samesite="strict", path=self.base, max_age=600)
        return response

