"""Approval out of band: the human answers in the operator console, not in the MCP client's form.

Why in the tool body and not in a resolver: waiting for a human in a browser is a long, stateful
exchange (send the link, wait for the console, withdraw the other question), and resolvers must
stay side-effect free. The body runs once per call, so this is where it happens:

- `url`: a URL-mode elicitation carries the link of the request's console page (one-time,
  unguessable, bound to the plan (its id and digest) and the e-stop generation, expiring with
  the plan; see `safety.pending`). The client's "accept" only means the human opened it; the decision is what
  the console records. Declined or cancelled link: refused.
- `both`: the form question and the console wait run side by side; the first answer wins and
  the other is withdrawn (the form's request is cancelled; the console request is closed).

Under protocol 2026-07-28 a tool cannot ask mid-call: the question goes out in an
`InputRequiredResult` and the client retries the call with its answers (`ask_round`, then
`answer_round` on the retry):

- round one carries a URL-mode elicitation with the console link, keyed by the request's id
  (and, for `both`, the form question beside it) and a `request_state` naming the plan, the board's request and a one-time
  round nonce, sealed with this daemon's HMAC key (`server.roundstate`);
- the retry proceeds from the board only: a console decision made before the retry answers; for
  `both`, otherwise the form's answer (accept or decline) does; otherwise, if the client
  accepted the link (the human opened it), the retry waits for the console as under 2025-11-25,
  until the operator answers, the plan expires or an e-stop latches. Still undecided then:
  refused. A state this daemon did not seal, for another plan, or already used once (replayed),
  an e-stop since the round, a declined link: refused.

Whatever happens, the answer handed to the Guard is read from the server-side record
(`ConsoleAnswer`), or is the form's own answer when the form won. The Guard then checks it is
for this very plan (digest) as for any approval.
"""

from __future__ import annotations

import contextlib
from typing import Any

import anyio
from mcp.server.elicitation import AcceptedUrlElicitation, render_elicitation_schema
from mcp.server.mcpserver import AcceptedElicitation, Context, DeclinedElicitation
from mcp_types import ElicitRequest, ElicitRequestFormParams, ElicitRequestURLParams, ElicitResult, InputRequiredResult
from pydantic import ValidationError

from armwarden.approval.board import PendingRequest
from armwarden.approval.decision import ApprovalForm, ConsoleAnswer, ConsoleChannel
from armwarden.guard import Guard
from armwarden.server.roundstate import RoundClaims, RoundSeal

__all__ = ["FORM_KEY", "answer_out_of_band", "answer_round", "ask_round"]

#: the key of the form question of a 2026-07-28 approval round (`InputRequiredResult.input_requests`);
#: the link's key is the request's id (2026-07-28 has no elicitation id on the wire: the key is it)
FORM_KEY = "armwarden_approval_form"

#: how often a pending console approval looks at the e-stop latch [s]
ESTOP_POLL_S = 0.1


def _open_request(guard: Guard, asked: ConsoleChannel, plan_id: str) -> tuple[PendingRequest, str] | ConsoleAnswer:
    """The board's open request for the asked plan (`plan_id`: this caller's, never another
    caller's plan of the same motion) and its console link, or the refusal that says why there
    is nothing to ask about (the request closed, or no console served)."""
    digest = asked.prompt.digest
    request = guard.approvals.open_for(plan_id, guard.latch.generation)
    if request is None or request.digest != digest:
        return ConsoleAnswer(False, None, digest, "the approval request is no longer open (plan expired or e-stop)")
    link = guard.approvals.link(request)
    if link is None:
        return ConsoleAnswer(False, None, digest, "approval.channel asks in the operator console, but no console is served")
    return request, link


async def answer_out_of_band(ctx: Context, guard: Guard, asked: ConsoleChannel, plan_id: str) -> Any:
    """Ask as `asked.channel` says about plan `plan_id` and return the outcome for
    `Guard.execute`: a `ConsoleAnswer` from the board, or the form's elicitation result when the
    form answered first."""
    opened = _open_request(guard, asked, plan_id)
    if isinstance(opened, ConsoleAnswer):
        return opened
    request, link = opened
    answered = anyio.Event()
    request.listeners.append(lambda _request: answered.set())
    outcome: dict[str, Any] = {}

    async def by_link(scope: anyio.CancelScope) -> None:
        result = await ctx.elicit_url(_link_message(request), link, request.request_id)
        if not isinstance(result, AcceptedUrlElicitation) and asked.channel == "url":
            outcome["missing"] = "the human did not open the approval link"
            scope.cancel()

    async def by_form(scope: anyio.CancelScope) -> None:
        result = await ctx.elicit(asked.prompt.message, ApprovalForm)
        outcome["form"] = result
        scope.cancel()

    async def by_console(scope: anyio.CancelScope) -> None:
        if (missing := await _wait_for_console(guard, request, answered)) is not None:
            outcome["missing"] = missing
        scope.cancel()

    with anyio.move_on_after(guard.approvals.remaining_s(request)):
        async with anyio.create_task_group() as group:
            group.start_soon(by_console, group.cancel_scope)
            group.start_soon(by_link if asked.channel == "url" else by_form, group.cancel_scope)
    return await _outcome(ctx, guard, request, outcome)


def _link_message(request: PendingRequest) -> str:
    return (f"Approve or decline plan {request.plan_id} (approval code {request.code}) in the ArmWarden "
            "operator console. The link works once and expires with the plan.")


async def _wait_for_console(guard: Guard, request: PendingRequest, answered: anyio.Event) -> str | None:
    """Wait until the console answers `request` (`answered` is set by its listener); the reason
    there will be no answer when an e-stop latched first."""
    # an e-stop from any path (also another thread's) voids the plan: stop waiting at once
    while not answered.is_set():
        if guard.latch.generation != request.estop_generation:
            return "an e-stop latched while the approval was pending; the plan is void"
        with anyio.move_on_after(ESTOP_POLL_S):
            await answered.wait()
    return None


async def _outcome(ctx: Context, guard: Guard, request: PendingRequest, outcome: dict[str, Any],
                   notify: bool = True) -> Any:
    """The first answer, read from where it was recorded; the other channel withdrawn."""
    if request.answer in ("approved", "declined"):
        if notify:
            await _complete(ctx, request)
        return ConsoleAnswer(request.answer == "approved", request.operator, request.digest,
                             self_approved=request.self_approved)
    if "form" in outcome:
        guard.approvals.withdraw(request.plan_id, "answered in the MCP client")
        return outcome["form"]
    guard.approvals.withdraw(request.plan_id, "no answer")
    return ConsoleAnswer(False, None, request.digest,
                         outcome.get("missing", f"no answer in the console before plan {request.plan_id} expired"))


async def _complete(ctx: Context, request: PendingRequest) -> None:
    """Tell the client the out-of-band question is settled (best effort: the answer stands anyway)."""
    with contextlib.suppress(Exception):
        await ctx.session.send_elicit_complete(request.request_id)


# ---------------------------------------------------------------------- protocol 2026-07-28
def ask_round(ctx: Context, guard: Guard, asked: ConsoleChannel, plan_id: str, seal: RoundSeal
              ) -> InputRequiredResult | ConsoleAnswer:
    """Round one: the console link as URL-mode elicitation (for `both`, with the form question
    when the client takes forms), and the sealed round state. A `ConsoleAnswer` (refusal) when
    there is nothing to ask about (the request closed, or no console served)."""
    opened = _open_request(guard, asked, plan_id)
    if isinstance(opened, ConsoleAnswer):
        return opened
    request, link = opened
    questions: dict[str, Any] = {request.request_id: ElicitRequest(params=ElicitRequestURLParams(
        message=_link_message(request), url=link))}
    if asked.channel == "both" and _takes_forms(ctx):
        questions[FORM_KEY] = ElicitRequest(params=ElicitRequestFormParams(
            message=asked.prompt.message, requested_schema=render_elicitation_schema(ApprovalForm)))
    claims = RoundClaims(plan_id=plan_id, request_id=request.request_id, digest=request.digest,
                         nonce=guard.approvals.start_round(request), channel=asked.channel)
    return InputRequiredResult(input_requests=questions, request_state=seal.seal(claims))


async def answer_round(ctx: Context, guard: Guard, asked: ConsoleChannel, plan_id: str, seal: RoundSeal) -> Any:
    """The retry: the outcome for `Guard.execute`, read from the board (or the form's answer,
    for `both`, when the console had not decided). Refusals are `ConsoleAnswer`s saying why."""
    digest = asked.prompt.digest
    board = guard.approvals

    def refusal(why: str) -> ConsoleAnswer:
        return ConsoleAnswer(False, None, digest, why)

    claims = seal.open(ctx.request_state)
    if claims is None:
        return refusal("the approval round's state was not issued by this daemon (forged, altered, or from before a restart)")
    request = board.get(claims.request_id)
    if (request is None or claims.plan_id != plan_id or request.plan_id != plan_id or claims.digest != digest
            or request.digest != digest):
        return refusal(f"the approval round's state is not about plan {plan_id}")
    if not board.spend_round(request, claims.nonce):
        return refusal("this approval round was already answered once (a replayed request state)")
    if request.estop_generation != guard.latch.generation:
        return refusal("an e-stop latched after the approval was asked; the plan is void")
    if request.answer == "withdrawn":
        return refusal(f"the approval request was closed ({request.via})")
    responses = ctx.input_responses or {}
    if request.answer is None and claims.channel == "both":
        form = _form_answer(responses.get(FORM_KEY))
        if form is not None:
            board.withdraw(request.plan_id, "answered in the MCP client")
            return form
    if request.answer is None:
        link = responses.get(request.request_id)
        if not (isinstance(link, ElicitResult) and link.action == "accept"):
            board.withdraw(request.plan_id, "no answer")
            return refusal("the human did not open the approval link")
        answered = anyio.Event()
        request.listeners.append(lambda _request: answered.set())
        outcome: dict[str, Any] = {}
        with anyio.move_on_after(board.remaining_s(request)):
            if (missing := await _wait_for_console(guard, request, answered)) is not None:
                outcome["missing"] = missing
        return await _outcome(ctx, guard, request, outcome, notify=False)
    return await _outcome(ctx, guard, request, {}, notify=False)


def _takes_forms(ctx: Context) -> bool:
    """Whether the client declared form elicitation (a bare `elicitation: {}` means forms)."""
    caps = ctx.client_capabilities
    elicitation = None if caps is None else caps.elicitation
    return elicitation is not None and (elicitation.form is not None or elicitation.url is None)


def _form_answer(response: object) -> Any:
    """The form's answer as the SDK would inject it (accepted with the validated form, or
    declined); None when the form was not answered (cancelled, or no response)."""
    if not isinstance(response, ElicitResult) or response.action == "cancel":
        return None
    if response.action == "decline":
        return DeclinedElicitation()
    try:
        return AcceptedElicitation[ApprovalForm](data=ApprovalForm.model_validate(response.content or {}))
    except ValidationError:
        return DeclinedElicitation()  # an answer that does not fit the form approves nothing
