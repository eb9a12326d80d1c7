"""The console's HTTP routes: pages, live fragments, pictures (the arm's top/side view, plan
previews, each camera's latest picture), and the four things a human can do (sign in/out, E-STOP,
release the e-stop, answer an approval request).

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

import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from importlib import resources
from typing import Any

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.routing import Route

from armwarden.approval.board import AnswerRefusal
from armwarden.audit import AuditWriteError
from armwarden.console.cameras import CameraFeed, CameraTrouble
from armwarden.console.feed import StateFeed, request_view
from armwarden.console.pages import (
    SECURITY_HEADERS,
    MessageKind,
    login_message,
    login_query,
    message_text,
    page_headers,
    render,
    render_fragment,
)
from armwarden.console.sessions import COOKIE, LOGIN_COOKIE, Session, SessionStore, SignInRefused, same_secret
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard import Guard
from armwarden.safety.refusals import RefusalReports, left_out_recorder
from armwarden.transport.http import CONSOLE_PATH, is_loopback_host

__all__ = ["CONSOLE_PATH", "ConsoleSettings", "EStopHook", "build_console_app", "timed_estop"]

logger = logging.getLogger(__name__)

#: latch the e-stop and stop the arm from any thread: (reason, principal, peer) -> e-stop event number
EStopHook = Callable[[str, str, str], int]
_FRAGMENTS = {"state": "_state.html", "safety": "_safety.html", "approvals": "_approvals.html", "audit": "_audit.html"}
_STATIC = {"console.js": "text/javascript; charset=utf-8", "console.css": "text/css; charset=utf-8"}


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


def _is_loopback_peer(request: Request) -> bool:
    client = request.client
    return client is not None and is_loopback_host(client.host)


class Console:
    """The handlers of one console, bound to one Guard."""

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

    # ------------------------------------------------------------------ sign-in
    async def login_page(self, request: Request) -> Response:
        message, kind = login_message(request.query_params) or (None, "ok")
        return self._login_form(message, kind)

    def _login_form(self, message: str | None, kind: MessageKind, status_code: int = 200) -> Response:
        """The sign-in page with its own CSRF cookie, saying `message` (None: nothing)."""
        import secrets

        token = secrets.token_urlsafe(24)
        response = render("login.html", status_code=status_code, base=self.base, login_csrf=token,
                          sign_in_enabled=self.sessions.enabled, headers=self.headers,
                          estop_url=self.settings.estop_url, message=message, message_kind=kind)
        response.set_cookie(LOGIN_COOKIE, token, httponly=True, samesite="strict", path=self.base, max_age=600)
        return response

    async def login(self, request: Request) -> Response:
        form = await self.form_of(request)
        expected = request.cookies.get(LOGIN_COOKIE, "")
        if not expected or not same_secret(form.get("csrf"), expected):
            return await self.refuse(request, None, 403, "sign-in refused: the form's CSRF token is missing or wrong")
        session = self.sessions.sign_in(form.get("token"))
        if isinstance(session, SignInRefused):
            if session.name is None:
                await self.audit_anonymous_refusal(request, "console_sign_in", "a sign-in with an unknown or revoked token",
                                                   reason=session.reason)
            else:  # a valid token the full console had no room for
                await self.audit("console_sign_in", None, "refused", f"a sign-in refused: {session.message}",
                                 principal=session.name, reason=session.reason,
                                 peer=request.client.host if request.client else None)
            code = {"invalid_token": "bad_token", "agent_token": "agent_token"}.get(session.reason, "console_full")
            return RedirectResponse(f"{self.base}/login?{login_query(code)}", status_code=303)
        await self.audit("console_sign_in", session, "ok", f"signed in as {session.name} ({session.role})",
                         token=session.token_fingerprint)
        response = RedirectResponse(f"{self.base}/", status_code=303)
        response.set_cookie(COOKIE, session.session_id, httponly=True, samesite="strict", path=self.base)
        response.delete_cookie(LOGIN_COOKIE, path=self.base)
        return response

    async def logout(self, request: Request) -> Response:
        session = self.session_of(request)
        if session is None:
            return RedirectResponse(f"{self.base}/login", status_code=303)
        if not self.csrf_ok(request, await self.form_of(request), session):
            return await self.refuse(request, session, 403, "sign-out refused: CSRF token missing or wrong")
        self.sessions.sign_out(session.session_id)
        await self.audit("console_sign_out", session, "ok", f"{session.name} signed out")
        response = RedirectResponse(f"{self.base}/login?{login_query('signed_out')}", status_code=303)
        response.delete_cookie(COOKIE, path=self.base)
        return response

    # ------------------------------------------------------------------ pages
    def _signed_in(self, handler: Callable[[Request, Session], Any]) -> Callable[[Request], Any]:
        async def page(request: Request) -> Response:
            session = self.session_of(request)
            if session is None:
                return RedirectResponse(f"{self.base}/login", status_code=303)
            return await handler(request, session)

        return page

    async def state_page(self, request: Request, session: Session) -> Response:
        return self.page("state.html", request, session, title="state", robot=await self.feed.robot(),
                         safety=self.feed.safety())

    async def safety_page(self, request: Request, session: Session) -> Response:
        return self.page("safety.html", request, session, title="safety", safety=self.feed.safety())

    async def approvals_page(self, request: Request, session: Session) -> Response:
        return self.page("approvals.html", request, session, title="approvals", approvals=self.feed.approvals())

    async def approval_page(self, request: Request, session: Session) -> Response:
        pending = self.guard.approvals.get(request.path_params["request_id"])
        if pending is None:
            return self.back(session, "/approvals", "no_request")
        return self.page("approval.html", request, session, title=f"approve {pending.plan_id}", r=request_view(pending),
                         answerable=self.settings.answer_approvals, own_request=pending.is_requested_by(session.name),
                         self_approval_allowed=self.guard.policy.approval.allow_self_approval)

    async def cameras_page(self, request: Request, session: Session) -> Response:
        return self.page("cameras.html", request, session, title="cameras", cameras=self.cameras.views(),
                         refresh_ms=self.cameras.refresh_ms, refresh_s=self.cameras.refresh_s)

    async def audit_page(self, request: Request, session: Session) -> Response:
        return self.page("audit.html", request, session, title="audit", records=await self.feed.audit_tail(),
                         audit_status=await self.feed.audit_status())

    # ------------------------------------------------------------------ live reads (session, no redirect)
    async def fragment(self, request: Request) -> Response:
        session = self.session_of(request)
        name = request.path_params["name"]
        if session is None or name not in _FRAGMENTS:
            return JSONResponse({"error": "sign in first" if session is None else "no such section"},
                                status_code=401 if session is None else 404, headers=SECURITY_HEADERS)
        context: dict[str, Any] = {"base": self.base, "session": session}
        if name == "state":
            context["robot"] = await self.feed.robot()
        elif name == "safety":
            context["safety"] = self.feed.safety()
        elif name == "approvals":
            context["approvals"] = self.feed.approvals()
        else:
            context.update(records=await self.feed.audit_tail(), audit_status=await self.feed.audit_status())
        return render_fragment(_FRAGMENTS[name], **context)

    async def state_json(self, request: Request) -> Response:
        if self.session_of(request) is None:
            return JSONResponse({"error": "sign in first"}, status_code=401, headers=SECURITY_HEADERS)
        return JSONResponse(await self.feed.snapshot(), headers=SECURITY_HEADERS)

    async def live_view(self, request: Request) -> Response:
        if self.session_of(request) is None:
            return Response(status_code=401, headers=SECURITY_HEADERS)
        png = await self.feed.live_picture()
        if png is None:
            return Response("no picture: the state is unavailable or Pillow is not installed", status_code=503,
                            headers=SECURITY_HEADERS)
        return Response(png, media_type="image/png", headers=SECURITY_HEADERS)

    async def plan_picture(self, request: Request) -> Response:
        pending = self.guard.approvals.get(request.path_params["request_id"])
        if self.session_of(request) is None or pending is None:
            return Response(status_code=401 if pending is not None else 404, headers=SECURITY_HEADERS)
        png = await self.feed.plan_picture(pending)
        if png is None:
            return Response("no picture (Pillow is not installed)", status_code=503, headers=SECURITY_HEADERS)
        return Response(png, media_type="image/png", headers=SECURITY_HEADERS)

    async def camera_picture(self, request: Request) -> Response:
        """A camera's latest picture (PNG), for any signed-in session; otherwise JSON ``{"error": why}``
        (401 not signed in, 404 no such camera, 403 the policy does not allow it, 503 the read failed, 429 the
        rate limits refuse a new read and there is no earlier picture)."""
        camera = request.path_params["camera"]
        if self.session_of(request) is None:
            return JSONResponse({"error": "sign in first"}, status_code=401, headers=SECURITY_HEADERS)
        if camera not in self.cameras.cameras:
            return JSONResponse({"error": self.cameras.unknown(camera)}, status_code=404, headers=SECURITY_HEADERS)
        latest = await self.cameras.latest(camera)
        if isinstance(latest, CameraTrouble):
            headers = dict(SECURITY_HEADERS)
            if latest.kind == "rate_limited":
                headers["Retry-After"] = str(max(1, round(self.cameras.refresh_s)))
            return JSONResponse({"error": latest.message, "camera": camera}, status_code=latest.status, headers=headers)
        return Response(latest.png, media_type="image/png", headers=SECURITY_HEADERS)

    async def static(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in _STATIC:
            return Response(status_code=404)
        body = (resources.files("armwarden.console") / "static" / name).read_bytes()
        return Response(body, media_type=_STATIC[name], headers={"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"})

    # ------------------------------------------------------------------ actions
    async def estop(self, request: Request) -> Response:
        """Latch and stop first, then audit and answer. Signed in: stops, and says so when the page's
        CSRF token is stale (a page open before a newer sign-in in another tab): a stop is never
        refused for it, since it can only make the robot safer and a request from another web site
        never gets here (the Host/Origin check refuses it first). A page whose session has ended
        (expired, pushed out, signed out) stops with its E-STOP ticket while its token is valid,
        as through the stop channel. Otherwise, not signed in: only from loopback, and only if the
        settings allow it."""
        session = self.session_of(request)
        peer = request.client.host if request.client else "?"
        form = await self.form_of(request)
        ticket_principal = None if session is not None else self.sessions.principal_for_ticket(form.get("ticket"))
        if session is not None:
            principal = session.name if self.csrf_ok(request, form, session) else f"{session.name} (stale CSRF token)"
        elif ticket_principal is not None:
            principal = ticket_principal
        elif self.settings.estop_from_loopback_without_sign_in and _is_loopback_peer(request):
            principal = f"console (not signed in, {peer})"
        else:
            return await self.refuse(request, None, 401, "E-STOP from the console needs sign-in from this address")
        try:
            event = self.estop_hook("operator console E-STOP", principal, peer)
        except Exception as exc:  # the stop may not have been issued: say so loudly
            logger.critical("console E-STOP failed: %s", exc)
            return self._answer_estop(request, session, None, f"the stop may NOT have been issued: {exc}")
        return self._answer_estop(request, session, event, None)

    def _answer_estop(self, request: Request, session: Session | None, event: int | None, error: str | None) -> Response:
        """JSON for the page's script; a browser without script: signed in, the Safety page with
        the session's flash; otherwise this answer's own page (nothing a link could repeat)."""
        if "application/json" in request.headers.get("accept", ""):
            body = {"estopped": True, "event": event} if error is None else {"error": error}
            return JSONResponse(body, status_code=200 if error is None else 500, headers=SECURITY_HEADERS)
        code = "estop_failed" if error is not None else "estop_latched"
        if session is not None:
            return self.back(session, "/safety", code, event)
        message, kind = message_text(code, event) or ("E-STOP: see the Safety page", "error")
        return self._login_form(message, kind, status_code=200 if error is None else 500)

    async def reset(self, request: Request) -> Response:
        """Release the e-stop: an operator types the number of the event shown; a newer latch refuses.
        So does a release by the token whose MCP call latched a held e-stop or asked to release it
        (`PendingApprovals.self_release`), unless `approval.allow_self_approval`."""
        session = self.session_of(request)
        if session is None:
            return await self.refuse(request, None, 401, "sign in to release the e-stop")
        form = await self.form_of(request)
        if not self.csrf_ok(request, form, session):
            return await self.refuse(request, session, 403, "release refused: CSRF token missing or wrong")
        if not session.can_approve:
            return await self.refuse(request, session, 403, "release refused: observers cannot release the e-stop")
        typed = form.get("event", "").strip().lstrip("#")
        own = self.guard.approvals.self_release(session.name, (e.number for e in self.guard.latch.held_events))
        if own is not None and not self.guard.policy.approval.allow_self_approval:
            why = (f"release refused: {session.name} {own}, so another operator must release it "
                   "(approval.allow_self_approval is off)")
            await self.audit("console_reset_estop", session, "refused_self_release", why, typed_event=typed[:32])
            return await self.refuse(request, session, 403, why)
        try:
            result = await self.guard.reset_estop_typed(typed, operator=session.name)  # recorded before it takes effect
        except SafetyRefusal as exc:
            with _told_even_if_unrecorded():  # a full audit disk may be why it was refused
                await self.audit("console_reset_estop", session, "refused", str(exc), typed_event=typed[:32])
            return self.back(session, "/safety", "release_unrecorded" if exc.code == RefusalCode.AUDIT_UNAVAILABLE
                             else "release_refused")
        with _told_even_if_unrecorded():  # the release itself was recorded before it took effect
            await self.audit("console_reset_estop", session, "released",
                             result.detail + (f"; by {session.name}, who {own} (approval.allow_self_approval is on)"
                                              if own is not None else ""),
                             released_event=result.released_event, self_release=own is not None)
        return self.back(session, "/safety", "released", result.released_event)

    async def answer(self, request: Request) -> Response:
        """Approve or decline one request, once; the waiting tool call proceeds from this record."""
        session = self.session_of(request)
        if session is None:
            return await self.refuse(request, None, 401, "sign in to answer approval requests")
        form = await self.form_of(request)
        if not self.csrf_ok(request, form, session):
            return await self.refuse(request, session, 403, "answer refused: CSRF token missing or wrong")
        if not session.can_approve:
            return await self.refuse(request, session, 403, "answer refused: observers cannot approve")
        if not self.settings.answer_approvals:
            return await self.refuse(request, session, 403, "answer refused: the policy's approval channel is "
                                     "'form' (answer in the MCP client)")
        decision = form.get("decision")
        if decision not in ("approve", "decline"):
            return await self.refuse(request, session, 400, "answer refused: decision must be approve or decline")
        request_id = request.path_params["request_id"]
        pending = self.guard.approvals.get(request_id)
        requester = None if pending is None else pending.requester
        outcome = self.guard.approvals.answer(request_id, decision == "approve", session.name,
                                              self.guard.latch.generation,
                                              allow_self_approval=self.guard.policy.approval.allow_self_approval)
        if isinstance(outcome, AnswerRefusal):
            await self.audit("console_approval", session, f"refused_{outcome.reason}", outcome.message,
                             requester=requester)
            status = 403 if outcome.reason == "self_approval" else 409
            return await self.refuse(request, session, status, f"answer refused: {outcome.message}")
        detail = f"plan {outcome.plan_id} {outcome.answer} in the console"
        if outcome.self_approved:
            detail += f" by its own requester {session.name} (approval.allow_self_approval is on)"
        await self.audit("console_approval", session, outcome.answer or "?", detail, plan_id=outcome.plan_id,
                         approval_code=outcome.code, requester=requester, self_approval=outcome.self_approved)
        return self.back(session, f"/approvals/{request_id}", "approved" if outcome.answer == "approved" else "declined")

    # ------------------------------------------------------------------ the app
    def routes(self) -> list[Route]:
        signed = self._signed_in
        return [
            Route("/", signed(self.state_page), methods=["GET"]),
            Route("/safety", signed(self.safety_page), methods=["GET"]),
            Route("/approvals", signed(self.approvals_page), methods=["GET"]),
            Route("/approvals/{request_id}", signed(self.approval_page), methods=["GET"]),
            Route("/approvals/{request_id}", self.answer, methods=["POST"]),
            Route("/approvals/{request_id}/picture.png", self.plan_picture, methods=["GET"]),
            Route("/audit", signed(self.audit_page), methods=["GET"]),
            Route("/cameras", signed(self.cameras_page), methods=["GET"]),
            Route("/cameras/{camera:path}.png", self.camera_picture, methods=["GET"]),
            Route("/login", self.login_page, methods=["GET"]),
            Route("/login", self.login, methods=["POST"]),
            Route("/logout", self.logout, methods=["POST"]),
            Route("/fragment/{name}", self.fragment, methods=["GET"]),
            Route("/api/state", self.state_json, methods=["GET"]),
            Route("/view.png", self.live_view, methods=["GET"]),
            Route("/static/{name}", self.static, methods=["GET"]),
            Route("/estop", self.estop, methods=["POST"]),
            Route("/reset", self.reset, methods=["POST"]),
        ]


def build_console_app(guard: Guard, sessions: SessionStore, estop: EStopHook,
                      settings: ConsoleSettings | None = None, refusals: RefusalReports | None = None,
                      clock: Callable[[], float] = time.monotonic) -> Starlette:
    """The console as an ASGI app, to be mounted at `settings.path` (beside /mcp, or alone on
    --console-port). Host/Origin checks are the mounting app's job (`transport/http.py`).
    `refusals`: the limit on records of anonymous refusals (its owner closes it). `clock`: the
    monotonic clock camera pictures age by (tests move it by hand)."""
    console = Console(guard, sessions, estop, settings or ConsoleSettings(), refusals, clock)
    return Starlette(routes=console.routes())


def timed_estop(latch_and_stop: Callable[[str, str], int], record: Callable[[Any], None]) -> EStopHook:
    """An `EStopHook` from the stop channel's parts: latch and stop, then audit (without waiting)
    as the channel does, with the time the stop took."""
    from armwarden.stopchannel.records import ChannelStop

    def hook(reason: str, principal: str, peer: str) -> int:
        started = time.monotonic()
        try:
            event = latch_and_stop(reason, principal)
        except Exception as exc:
            record(ChannelStop(principal, reason, f"console {peer}", None, None, str(exc)))
            raise
        record(ChannelStop(principal, reason, f"console {peer}", event, (time.monotonic() - started) * 1e3))
        return event

    return hook


@contextlib.contextmanager
def _told_even_if_unrecorded() -> Iterator[None]:
    """The console's own record of a reset could not be written: logged, and the operator is still
    told what happened (the release, if any, was recorded before it took effect)."""
    try:
        yield
    except AuditWriteError as exc:
        logger.critical("console reset_estop: its record could not be written: %s", exc)
