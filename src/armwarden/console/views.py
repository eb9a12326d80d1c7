"""What the console shows: its pages (signed in, or redirected to sign-in) and the live reads the
pages' script polls (a session, no redirect: 401). Reads change nothing, so they are not audited.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response

from armwarden.console.cameras import CameraTrouble
from armwarden.console.core import ConsoleCore
from armwarden.console.feed import request_view
from armwarden.console.pages import SECURITY_HEADERS, render_fragment
from armwarden.console.sessions import Session

_FRAGMENTS = {"state": "_state.html", "safety": "_safety.html", "approvals": "_approvals.html", "audit": "_audit.html"}
_STATIC = {"console.js": "text/javascript; charset=utf-8", "console.css": "text/css; charset=utf-8"}


class Views:
    """The page and read handlers of one console."""

    def __init__(self, core: ConsoleCore) -> None:
        self.core = core

    def signed_in(self, handler: Callable[[Request, Session], Any]) -> Callable[[Request], Any]:
        async def page(request: Request) -> Response:
            session = self.core.session_of(request)
            if session is None:
                return RedirectResponse(f"{self.core.base}/login", status_code=303)
            return await handler(request, session)

        return page

    async def state_page(self, request: Request, session: Session) -> Response:
        return self.core.page("state.html", request, session, title="state", robot=await self.core.feed.robot(),
                              safety=self.core.feed.safety())

    async def safety_page(self, request: Request, session: Session) -> Response:
        return self.core.page("safety.html", request, session, title="safety", safety=self.core.feed.safety())

    async def approvals_page(self, request: Request, session: Session) -> Response:
        return self.core.page("approvals.html", request, session, title="approvals", approvals=self.core.feed.approvals())

    async def approval_page(self, request: Request, session: Session) -> Response:
        pending = self.core.guard.approvals.get(request.path_params["request_id"])
        if pending is None:
            return self.core.back(session, "/approvals", "no_request")
        return self.core.page("approval.html", request, session, title=f"approve {pending.plan_id}", r=request_view(pending),
                              answerable=self.core.settings.answer_approvals, own_request=pending.is_requested_by(session.name),
                              self_approval_allowed=self.core.guard.policy.approval.allow_self_approval)

    async def cameras_page(self, request: Request, session: Session) -> Response:
        return self.core.page("cameras.html", request, session, title="cameras", cameras=self.core.cameras.views(),
                              refresh_ms=self.core.cameras.refresh_ms, refresh_s=self.core.cameras.refresh_s)

    async def audit_page(self, request: Request, session: Session) -> Response:
        return self.core.page("audit.html", request, session, title="audit", records=await self.core.feed.audit_tail(),
                              audit_status=await self.core.feed.audit_status())

    # ------------------------------------------------------------------ live reads (session, no redirect)
    async def fragment(self, request: Request) -> Response:
        session = self.core.session_of(request)
        name = request.path_params["name"]
        if session is None or name not in _FRAGMENTS:
            return JSONResponse({"error": "sign in first" if session is None else "no such section"},
                                status_code=401 if session is None else 404, headers=SECURITY_HEADERS)
        context: dict[str, Any] = {"base": self.core.base, "session": session}
        if name == "state":
            context["robot"] = await self.core.feed.robot()
        elif name == "safety":
            context["safety"] = self.core.feed.safety()
        elif name == "approvals":
            context["approvals"] = self.core.feed.approvals()
        else:
            context.update(records=await self.core.feed.audit_tail(), audit_status=await self.core.feed.audit_status())
        return render_fragment(_FRAGMENTS[name], **context)

    async def state_json(self, request: Request) -> Response:
        if self.core.session_of(request) is None:
            return JSONResponse({"error": "sign in first"}, status_code=401, headers=SECURITY_HEADERS)
        return JSONResponse(await self.core.feed.snapshot(), headers=SECURITY_HEADERS)

    async def live_view(self, request: Request) -> Response:
        if self.core.session_of(request) is None:
            return Response(status_code=401, headers=SECURITY_HEADERS)
        png = await self.core.feed.live_picture()
        if png is None:
            return Response("no picture: the state is unavailable or Pillow is not installed", status_code=503,
                            headers=SECURITY_HEADERS)
        return Response(png, media_type="image/png", headers=SECURITY_HEADERS)

    async def plan_picture(self, request: Request) -> Response:
        pending = self.core.guard.approvals.get(request.path_params["request_id"])
        if self.core.session_of(request) is None or pending is None:
            return Response(status_code=401 if pending is not None else 404, headers=SECURITY_HEADERS)
        png = await self.core.feed.plan_picture(pending)
        if png is None:
            return Response("no picture (Pillow is not installed)", status_code=503, headers=SECURITY_HEADERS)
        return Response(png, media_type="image/png", headers=SECURITY_HEADERS)

    async def camera_picture(self, request: Request) -> Response:
        """A camera's latest picture (PNG), for any signed-in session; otherwise JSON ``{"error": why}``
        (401 not signed in, 404 no such camera, 403 the policy does not allow it, 503 the read failed, 429 the
        rate limits refuse a new read and there is no earlier picture)."""
        camera = request.path_params["camera"]
        if self.core.session_of(request) is None:
            return JSONResponse({"error": "sign in first"}, status_code=401, headers=SECURITY_HEADERS)
        if camera not in self.core.cameras.cameras:
            return JSONResponse({"error": self.core.cameras.unknown(camera)}, status_code=404, headers=SECURITY_HEADERS)
        latest = await self.core.cameras.latest(camera)
        if isinstance(latest, CameraTrouble):
            headers = dict(SECURITY_HEADERS)
            if latest.kind == "rate_limited":
                headers["Retry-After"] = str(max(1, round(self.core.cameras.refresh_s)))
            return JSONResponse({"error": latest.message, "camera": camera}, status_code=latest.status, headers=headers)
        return Response(latest.png, media_type="image/png", headers=SECURITY_HEADERS)

    async def static(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in _STATIC:
            return Response(status_code=404)
        body = (resources.files("armwarden.console") / "static" / name).read_bytes()
        return Response(body, media_type=_STATIC[name], headers={"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"})
