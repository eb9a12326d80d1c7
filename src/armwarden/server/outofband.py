"""Approval out of band: the human answers in the operator console, not in the MCP client's form.

Why in the tool body and not in a resolver: waiting for a human in a browser is a long, stateful
exchange (send the link, wait for the console, withdraw the other question), and resolvers must
stay side-effect free. The body runs once per call, so this is where it happens:

- `url`: a URL-mode elicitation carries the link of the request's console page (one-time,
  unguessable, bound to the plan digest and the e-stop generation, expiring with the plan; see
  `safety.pending`). The client's "accept" only means the human opened it; the decision is what
  the console records. Declined or cancelled link: refused.
- `both`: the form question and the console wait run side by side; the first answer wins and
  the other is withdrawn (the form's request is cancelled; the console request is closed).

Whatever happens, the answer handed to the Guard is read from the server-side record
(`ConsoleAnswer`), or is the form's own answer when the form won. The Guard then checks it is
for this very plan (digest) as for any approval.
"""

from __future__ import annotations

import contextlib
from typing import Any

import anyio
from mcp.server.elicitation import AcceptedUrlElicitation
from mcp.server.mcpserver import Context

from armwarden.guard import Guard
from armwarden.safety.approval import ApprovalForm, ConsoleAnswer, ConsoleChannel
from armwarden.safety.pending import PendingRequest

__all__ = ["answer_out_of_band"]

#: how often a pending console approval looks at the e-stop latch [s]
ESTOP_POLL_S = 0.1


async def answer_out_of_band(ctx: Context, guard: Guard, asked: ConsoleChannel) -> Any:
    """Ask as `asked.channel` says and return the outcome for `Guard.execute`: a `ConsoleAnswer`
    from the board, or the form's elicitation result when the form answered first."""
    digest = asked.prompt.digest
    board = guard.approvals
    request = board.open_for(digest, guard.latch.generation)
    if request is None:
        return ConsoleAnswer(False, None, digest, "the approval request is no longer open (plan expired or e-stop)")
    link = board.link(request)
    if link is None:
        return ConsoleAnswer(False, None, digest, "approval.channel asks in the operator console, but no console is served")
    answered = anyio.Event()
    request.listeners.append(lambda _request: answered.set())
    outcome: dict[str, Any] = {}

    async def by_link(scope: anyio.CancelScope) -> None:
        message = (f"Approve or decline plan {request.plan_id} (approval code {request.code}) in the ArmWarden "
                   "operator console. The link works once and expires with the plan.")
        result = await ctx.elicit_url(message, link, request.request_id)
        if not isinstance(result, AcceptedUrlElicitation) and asked.channel == "url":
            outcome["missing"] = "the human did not open the approval link"
            scope.cancel()

    async def by_form(scope: anyio.CancelScope) -> None:
        result = await ctx.elicit(asked.prompt.message, ApprovalForm)
        outcome["form"] = result
        scope.cancel()

    async def by_console(scope: anyio.CancelScope) -> None:
        # an e-stop from any path (also another thread's) voids the plan: stop waiting at once
        while not answered.is_set():
            if guard.latch.generation != request.estop_generation:
                outcome["missing"] = "an e-stop latched while the approval was pending; the plan is void"
                break
            with anyio.move_on_after(ESTOP_POLL_S):
                await answered.wait()
        scope.cancel()

    with anyio.move_on_after(board.remaining_s(request)):
        async with anyio.create_task_group() as group:
            group.start_soon(by_console, group.cancel_scope)
            group.start_soon(by_link if asked.channel == "url" else by_form, group.cancel_scope)
    return await _outcome(ctx, guard, request, outcome)


async def _outcome(ctx: Context, guard: Guard, request: PendingRequest, outcome: dict[str, Any]) -> Any:
    """The first answer, read from where it was recorded; the other channel withdrawn."""
    if request.answer in ("approved", "declined"):
        await _complete(ctx, request)
        return ConsoleAnswer(request.answer == "approved", request.operator, request.digest)
    if "form" in outcome:
        guard.approvals.withdraw(request.digest, "answered in the MCP client")
        return outcome["form"]
    guard.approvals.withdraw(request.digest, "no answer")
    return ConsoleAnswer(False, None, request.digest,
                         outcome.get("missing", f"no answer in the console before plan {request.plan_id} expired"))


async def _complete(ctx: Context, request: PendingRequest) -> None:
    """Tell the client the out-of-band question is settled (best effort: the answer stands anyway)."""
    with contextlib.suppress(Exception):
        await ctx.session.send_elicit_complete(request.request_id)
