"""Signing in and out of the console: the sign-in form with its own CSRF cookie, a token
exchanged for a session (audited; refusals of unknown tokens rate-limited), and signing out.
"""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import RedirectResponse, Response

from armwarden.console.core import ConsoleCore
from armwarden.console.pages import login_message, login_query
from armwarden.console.sessions import COOKIE, LOGIN_COOKIE, SignInRefused, same_secret


class SignIn:
    """The sign-in handlers of one console."""

    def __init__(self, core: ConsoleCore) -> None:
        self.core = core

    async def login_page(self, request: Request) -> Response:
        message, kind = login_message(request.query_params) or (None, "ok")
        return self.core.login_form(message, kind)

    async def login(self, request: Request) -> Response:
        form = await self.core.form_of(request)
        expected = request.cookies.get(LOGIN_COOKIE, "")
        if not expected or not same_secret(form.get("csrf"), expected):
            return await self.core.refuse(request, None, 403, "sign-in refused: the form's CSRF token is missing or wrong")
        session = self.core.sessions.sign_in(form.get("token"))
        if isinstance(session, SignInRefused):
            if session.name is None:
                await self.core.audit_anonymous_refusal(request, "console_sign_in", "a sign-in with an unknown or revoked token",
                                                        reason=session.reason)
            else:  # a valid token the full console had no room for
                await self.core.audit("console_sign_in", None, "refused", f"a sign-in refused: {session.message}",
                                      principal=session.name, reason=session.reason,
                                      peer=request.client.host if request.client else None)
            code = {"invalid_token": "bad_token", "agent_token": "agent_token"}.get(session.reason, "console_full")
            return RedirectResponse(f"{self.core.base}/login?{login_query(code)}", status_code=303)
        await self.core.audit("console_sign_in", session, "ok", f"signed in as {session.name} ({session.role})",
                              token=session.token_fingerprint)
        response = RedirectResponse(f"{self.core.base}/", status_code=303)
        response.set_cookie(COOKIE, session.session_id, httponly=True, samesite="strict", path=self.core.base)
        response.delete_cookie(LOGIN_COOKIE, path=self.core.base)
        return response

    async def logout(self, request: Request) -> Response:
        session = self.core.session_of(request)
        if session is None:
            return RedirectResponse(f"{self.core.base}/login", status_code=303)
        if not self.core.csrf_ok(request, await self.core.form_of(request), session):
            return await self.core.refuse(request, session, 403, "sign-out refused: CSRF token missing or wrong")
        self.core.sessions.sign_out(session.session_id)
        await self.core.audit("console_sign_out", session, "ok", f"{session.name} signed out")
        response = RedirectResponse(f"{self.core.base}/login?{login_query('signed_out')}", status_code=303)
        response.delete_cookie(COOKIE, path=self.core.base)
        return response
