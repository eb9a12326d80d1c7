"""The approval side of the tool layer: the two hidden parameters of every tool that may need a
human, and whether a human can be asked on a request.

Each such tool declares `approval: Annotated[ApprovalAnswer, gate.approval]` and
`shown: Annotated[ShownDigest, gate.shown]` with `gate = approval_parameters(precheck)`. The SDK
resolves both (they never appear in the input schema); the resolvers only read state.
"""

from collections.abc import Callable
from typing import Annotated, Any, NamedTuple

from mcp.server.mcpserver import Context, Elicit, ElicitationResult, Resolve
from mcp.server.mcpserver.resolve import build_resolver_plans, find_resolved_parameters, resolve_arguments
from mcp_types import InputRequiredResult
from mcp_types.version import is_version_at_least

from armwarden.approval.decision import ApprovalForm, ConsoleChannel, Prompt, ServerDecision, form_under_channel
from armwarden.server.calls import current_call

#: a tool's hidden `approval` parameter: the server's decision or the human's answer
ApprovalAnswer = ElicitationResult[ApprovalForm]
#: a tool's hidden `shown` parameter: the digest of what the human was shown (None: nobody asked)
ShownDigest = str | None


def can_elicit(ctx: Context) -> bool:
    """Whether a human can be asked on this request (capability and a channel to ask on)."""
    caps = ctx.client_capabilities
    if caps is None or caps.elicitation is None:
        return False
    if ctx.protocol_version and is_version_at_least(ctx.protocol_version, "2026-07-28"):
        return True  # the question rides the InputRequiredResult
    return bool(ctx.session.can_send_request)


class ApprovalGate(NamedTuple):
    """The `Resolve` markers of the two hidden parameters of a tool that may need a human:
    `approval: Annotated[ApprovalAnswer, gate.approval]`, `shown: Annotated[ShownDigest, gate.shown]`."""

    approval: Resolve
    shown: Resolve


def console_reachable(ctx: Context) -> bool:
    """Whether the out-of-band console channel can be offered on this request: the client takes
    URL-mode elicitation, and the link can reach it: in an InputRequiredResult (2026-07-28, see
    `uses_rounds`) or as a server-to-client request mid-call (2025-11-25)."""
    caps = ctx.client_capabilities
    if caps is None or caps.elicitation is None or caps.elicitation.url is None:
        return False
    if uses_rounds(ctx):
        return True
    return bool(ctx.session.can_send_request)


def uses_rounds(ctx: Context) -> bool:
    """Whether questions go out in an InputRequiredResult and come back on a retry (protocol
    2026-07-28 and later) rather than mid-call."""
    return bool(ctx.protocol_version) and is_version_at_least(str(ctx.protocol_version), "2026-07-28")


def approval_parameters(precheck: Callable[..., Any], approval: Any, action: str, console: bool = False) -> ApprovalGate:
    """The two hidden parameters of a tool that may need a human, both resolved from `precheck`
    (a read-only `ServerDecision | Prompt`; the SDK runs it once per round and shares it):
    `approval`, the server's decision or the human's answer to the prompt; `shown`, the digest of
    what that prompt showed (None when nobody was asked), which the Guard matches against the
    request it is about to carry out. `approval` (the policy's approval section) decides where
    the human answers: for a tool that can ask in the console (`console`: execute_plan), with
    channel url or both and a client that can open a link (`console_reachable`), the answer is
    a `ConsoleChannel`: the tool body asks out of band (`server.outofband`). Otherwise the form,
    as `form_under_channel` allows it (under url: refused, or led by the self-approval note)."""
    check = Resolve(precheck)

    async def ask(ctx: Context, result: Annotated[ServerDecision | Prompt, check]
                  ) -> ServerDecision | ConsoleChannel | Elicit[ApprovalForm]:
        if not isinstance(result, Prompt):
            return result
        record = current_call()
        if console and approval.channel in ("url", "both") and console_reachable(ctx):
            if record is not None:  # the audit record shows the question (protocol 2025-11-25 asks mid-call)
                record.extra["approval_prompt"] = result.message
            return ConsoleChannel(result, "url" if approval.channel == "url" else "both")
        form = form_under_channel(approval, action, result)
        if isinstance(form, ServerDecision):
            return form
        if record is not None:
            record.extra["approval_prompt"] = form.message
        return Elicit(form.message, ApprovalForm)

    async def shown(result: Annotated[ServerDecision | Prompt, check]) -> str | None:
        return result.digest if isinstance(result, Prompt) else None

    return ApprovalGate(Resolve(ask), Resolve(shown))


class ResolvedByHand:
    """Runs an `ApprovalGate`'s resolvers from inside a tool body, as the SDK would before it.

    Why: under 2026-07-28 the out-of-band channel sends its own InputRequiredResult from the
    body, and the SDK refuses that from a tool whose parameters use `Resolve` (one
    input_required channel per call). A tool that needs both declares no resolved parameters
    and calls this first: the SDK's own resolution (same resolvers, same wire keys, same sealed
    state for the form), then the body decides."""

    def __init__(self, gate: ApprovalGate, tool_arg_names: set[str]) -> None:
        def parameters(approval: Annotated[ApprovalAnswer, gate.approval],
                       shown: Annotated[ShownDigest, gate.shown]) -> None:
            """The hidden parameters, as a tool would declare them."""

        self._params = find_resolved_parameters(parameters)
        self._plans = build_resolver_plans(self._params, tool_arg_names)

    async def __call__(self, ctx: Context, **tool_args: Any) -> tuple[ApprovalAnswer, ShownDigest] | InputRequiredResult:
        """(approval, shown), or the question round the SDK's resolvers asked for."""
        resolved = await resolve_arguments(self._params, self._plans, tool_args, ctx)
        if isinstance(resolved, InputRequiredResult):
            return resolved
        return resolved["approval"], resolved["shown"]


__all__ = ["ApprovalAnswer", "ApprovalGate", "ResolvedByHand", "ShownDigest", "approval_parameters", "can_elicit",
           "console_reachable", "uses_rounds"]
