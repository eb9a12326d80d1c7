"""The things a human does in the console that change the robot or the approvals: E-STOP,
release the e-stop, answer an approval request. Each is refused unless its rules hold and is
audited either way; the E-STOP stops first and audits after, and is never refused for a stale
CSRF token.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from armwarden.approval.board import AnswerRefusal
from armwarden.audit import AuditWriteError
from armwarden.console.core import ConsoleCore, EStopHook, is_loopback_peer
from armwarden.console.pages import SECURITY_HEADERS, message_text
from armwarden.console.sessions import Session
from armwarden.core.errors import RefusalCode, SafetyRefusal

__all__ = ["Actions", "timed_estop"]

logger = logging.getLogger(__name__)


class Actions:
    """The action handlers of one console."""

    def __init__(self, core: ConsoleCore) -> None:
        self.core = core

    async def estop(self, request: Request) -> Response:
        """Latch and stop first, then audit and answer. Signed in: stops, and says so when the page's
        CSRF token is stale (a page open before a newer sign-in in another tab): a stop is never
        refused for it, since it can only make the robot safer and a request from another web site
        never gets here (the Host/Origin check refuses it first). A page whose session has ended
        (expired, pushed out, signed out) stops with its E-STOP ticket while its token is valid,
        as through the stop channel. Otherwise, not signed in: only from loopback, and only if the
        settings allow it."""
        session = self.core.session_of(request)
        peer = request.client.host if request.client else "?"
        form = await self.core.form_of(request)
        ticket_principal = None if session is not None else self.core.sessions.principal_for_ticket(form.get("ticket"))
        if session is not None:
            principal = session.name if self.core.csrf_ok(request, form, session) else f"{session.name} (stale CSRF token)"
        elif ticket_principal is not None:
            principal = ticket_principal
        elif self.core.settings.estop_from_loopback_without_sign_in and is_loopback_peer(request):
            principal = f"console (not signed in, {peer})"
        else:
            return await self.core.refuse(request, None, 401, "E-STOP from the console needs sign-in from this address")
        try:
            event = self.core.estop_hook("operator console E-STOP", principal, peer)
        except Exception as exc:  # the stop may not have been issued: say so loudly
            logger.critical("console E-STOP failed: %s", exc)
            return self._answer_estop(request, session, None, f"the stop may NOT have been issued: {exc}")
        return self._answer_estop(request, session, event, None)

    async def _approver(self, request: Request, to_do: str, action: str,
                        observers_cannot: str) -> tuple[Session, dict[str, str]] | Response:
        """The session and form of an operator who may approve, checked in this order: signed in
        (else 401 "sign in to `to_do`"), the form's CSRF token, not an observer (else 403 "`action`
        refused: ..."); a refusal is the audited response to return."""
        session = self.core.session_of(request)
        if session is None:
            return await self.core.refuse(request, None, 401, f"sign in to {to_do}")
        form = await self.core.form_of(request)
        if not self.core.csrf_ok(request, form, session):
            return await self.core.refuse(request, session, 403, f"{action} refused: CSRF token missing or wrong")
        if not session.can_approve:
            return await self.core.refuse(request, session, 403, f"{action} refused: observers cannot {observers_cannot}")
        return session, form

    def _answer_estop(self, request: Request, session: Session | None, event: int | None, error: str | None) -> Response:
        """JSON for the page's script; a browser without script: signed in, the Safety page with
        the session's flash; otherwise this answer's own page (nothing a link could repeat)."""
        if "application/json" in request.headers.get("accept", ""):
            body = {"estopped": True, "event": event} if error is None else {"error": error}
            return JSONResponse(body, status_code=200 if error is None else 500, headers=SECURITY_HEADERS)
        code = "estop_failed" if error is not None else "estop_latched"
        if session is not None:
            return self.core.back(session, "/safety", code, event)
        message, kind = message_text(code, event) or ("E-STOP: see the Safety page", "error")
        return self.core.login_form(message, kind, status_code=200 if error is None else 500)

    async def reset(self, request: Request) -> Response:
        """Release the e-stop: an operator types the number of the event shown; a newer latch refuses.
        So does a release by the token whose MCP call latched a held e-stop or asked to release it
        (`PendingApprovals.self_release`), unless `approval.allow_self_approval`."""
        signed_in = await self._approver(request, "release the e-stop", "release", "release the e-stop")
        if isinstance(signed_in, Response):
            return signed_in
        session, form = signed_in
        typed = form.get("event", "").strip().lstrip("#")
        own = self.core.guard.approvals.self_release(session.name, (e.number for e in self.core.guard.latch.held_events))
        if own is not None and not self.core.guard.policy.approval.allow_self_approval:
            why = (f"release refused: {session.name} {own}, so another operator must release it "
                   "(approval.allow_self_approval is off)")
            await self.core.audit("console_reset_estop", session, "refused_self_release", why, typed_event=typed[:32])
            return await self.core.refuse(request, session, 403, why)
        try:
            result = await self.core.guard.reset_estop_typed(typed, operator=session.name)  # recorded before it takes effect
        except SafetyRefusal as exc:
            with _told_even_if_unrecorded():  # a full audit disk may be why it was refused
                await self.core.audit("console_reset_estop", session, "refused", str(exc), typed_event=typed[:32])
            return self.core.back(session, "/safety", "release_unrecorded" if exc.code == RefusalCode.AUDIT_UNAVAILABLE
                                  else "release_refused")
        with _told_even_if_unrecorded():  # the release itself was recorded before it took effect
            await self.core.audit("console_reset_estop", session, "released",
                                  result.detail + (f"; by {session.name}, who {own} (approval.allow_self_approval is on)"
                                                   if own is not None else ""),
                                  released_event=result.released_event, self_release=own is not None)
        return self.core.back(session, "/safety", "released", result.released_event)

    async def answer(self, request: Request) -> Response:
        """Approve or decline one request, once; the waiting tool call proceeds from this record."""
        signed_in = await self._approver(request, "answer approval requests", "answer", "approve")
        if isinstance(signed_in, Response):
            return signed_in
        session, form = signed_in
        if not self.core.settings.answer_approvals:
            return await self.core.refuse(request, session, 403, "answer refused: the policy's approval channel is "
                                          "'form' (answer in the MCP client)")
        decision = form.get("decision")
        if decision not in ("approve", "decline"):
            return await self.core.refuse(request, session, 400, "answer refused: decision must be approve or decline")
        request_id = request.path_params["request_id"]
        pending = self.core.guard.approvals.get(request_id)
        requester = None if pending is None else pending.requester
        outcome = self.core.guard.approvals.answer(request_id, decision == "approve", session.name,
                                                   self.core.guard.latch.generation,
                                                   allow_self_approval=self.core.guard.policy.approval.allow_self_approval)
        if isinstance(outcome, AnswerRefusal):
            await self.core.audit("console_approval", session, f"refused_{outcome.reason}", outcome.message,
                                  requester=requester)
            status = 403 if outcome.reason == "self_approval" else 409
            return await self.core.refuse(request, session, status, f"answer refused: {outcome.message}")
        detail = f"plan {outcome.plan_id} {outcome.answer} in the console"
        if outcome.self_approved:
            detail += f" by its own requester {session.name} (approval.allow_self_approval is on)"
        await self.core.audit("console_approval", session, outcome.answer or "?", detail, plan_id=outcome.plan_id,
                              approval_code=outcome.code, requester=requester, self_approval=outcome.self_approved)
        return self.core.back(session, f"/approvals/{request_id}", "approved" if outcome.answer == "approved" else "declined")


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
