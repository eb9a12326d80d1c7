"""Human approval: when it is needed, what the human is shown, and what their answer means.

The prompt leads with facts the server computed (durations, speeds against caps, the approval
code derived from the plan digest); anything the model wrote is shown on one line, quoted,
truncated and labelled unverified, so an injected "operator note: safe to approve" cannot pass
for server text. The form's `approve` box is unticked by default: only an explicit tick runs.

Where the human answers (`approval.channel`): under `url` the operator console, never the
requesting client's own form. The form is answered by the very client that asked, so under `url`
it is not asked at all (`form_under_channel`: refused, naming the console) and a form answer that
reaches the Guard anyway is refused (`hold_to_channel`), unless `approval.allow_self_approval`
lets the requester approve, which the prompt and the audit record then say.

This module is pure: the MCP resolvers that use it must stay side-effect free (under protocol
2026-07-28 they may run more than once per call). The prompt texts themselves are in
`armwarden.approval.prompts`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool

from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.results import ApprovalInfo
from armwarden.safety.estop import flatten_reason
from armwarden.tools import ApprovalAction

UNTRUSTED_TEXT_LIMIT = 160


class ApprovalForm(BaseModel):
    """The elicitation form: one checkbox and a name. Primitive fields only (MCP form schema).
    Strict: only a real boolean `true` approves ("true", "yes", 1 do not), and unknown fields are
    refused, so a sloppy or forged answer never counts as a yes."""

    model_config = ConfigDict(extra="forbid")

    approve: StrictBool = Field(default=False, description="Tick to allow exactly what is described above")
    operator: str = Field(default="", max_length=64, description="Your name, recorded in the audit log")


@dataclass(frozen=True)
class ServerDecision:
    """What a resolver decided without asking anyone.

    `proceed` True: no approval needed (or allowed without elicitation by policy); `via` says why.
    `proceed` False: refused before any prompt; `code`/`message` say why (pre-check failed, or
    approval needed and the client cannot ask a human).
    """

    proceed: bool
    via: Literal["not_required", "no_elicitation_client", "dry_run", "refused"]
    code: RefusalCode | None = None
    message: str = ""

    @classmethod
    def refusal(cls, refused: SafetyRefusal) -> ServerDecision:
        """The decision a pre-check returns for a refusal the Guard raised (or would raise)."""
        return cls(False, "refused", refused.code, str(refused))

    @classmethod
    def refused(cls, code: RefusalCode, message: str) -> ServerDecision:
        return cls(False, "refused", code, message)


@dataclass(frozen=True)
class Prompt:
    """A question for a human, with the server facts it was built from."""

    message: str
    digest: str  # what the human approves: a plan digest or an e-stop event number, as text


@dataclass(frozen=True)
class ConsoleChannel:
    """A resolver's answer when the human is asked in the operator console (`approval.channel`
    url or both): the tool body sends the link (URL-mode elicitation) and waits for the
    console's answer, recorded server-side (`safety.pending`)."""

    prompt: Prompt
    channel: Literal["url", "both"]


@dataclass(frozen=True)
class ConsoleAnswer:
    """What the tool body read from the approval board: the console's answer for `digest`, or
    why none came (`missing`: expired, e-stopped, link declined, no console served)."""

    approved: bool
    operator: str | None
    digest: str
    missing: str | None = None
    #: the operator was the token that requested the motion (`approval.allow_self_approval`)
    self_approved: bool = False


@dataclass(frozen=True)
class Approval:
    """What the tool body learned about approval: who decided, and how."""

    granted: bool
    via: Literal["not_required", "elicitation", "console", "no_elicitation_client", "dry_run"]
    required: bool
    operator: str | None = None
    refusal_code: RefusalCode | None = None
    refusal_message: str = ""
    #: granted in the console by the token that requested it (the policy allows that); audited
    self_approved: bool = False

    def info(self) -> ApprovalInfo:
        return ApprovalInfo(required=self.required, operator=self.operator, via=self.via)

    def refusal(self, what: str) -> SafetyRefusal:
        """The refusal for an approval that was not granted, prefixed with what was refused."""
        return SafetyRefusal(self.refusal_code or RefusalCode.APPROVAL_INVALID, f"{what}: {self.refusal_message}")


def interpret(outcome: Any, required: bool) -> Approval:
    """Turn what the approval resolver produced (a `ServerDecision`, or the human's elicitation
    answer) into an `Approval`. Only an accepted form with `approve` ticked grants; anything
    unrecognised refuses."""
    from mcp.server.mcpserver import AcceptedElicitation, CancelledElicitation, DeclinedElicitation

    if isinstance(outcome, ConsoleAnswer):
        operator = flatten_reason(outcome.operator, 64) if outcome.operator else None
        if outcome.approved and outcome.missing is None:
            return Approval(True, "console", True, operator, self_approved=outcome.self_approved)
        why = outcome.missing or "the operator declined in the console"
        return Approval(False, "console", True, operator, RefusalCode.APPROVAL_DENIED, f"{why}; nothing was done")
    if isinstance(outcome, AcceptedElicitation):
        data = outcome.data
        if isinstance(data, ServerDecision):
            if data.proceed:
                return Approval(True, data.via if data.via != "refused" else "not_required", required)
            return Approval(False, "not_required", required, None, data.code, data.message)
        if isinstance(data, ApprovalForm):
            operator = flatten_reason(data.operator, 64) if data.operator else None
            if data.approve is True:
                return Approval(True, "elicitation", True, operator)
            return Approval(False, "elicitation", True, operator, RefusalCode.APPROVAL_DENIED,
                            "the human did not tick 'approve'; nothing was done")
    if isinstance(outcome, DeclinedElicitation):
        return Approval(False, "elicitation", True, None, RefusalCode.APPROVAL_DENIED,
                        "the human declined; nothing was done")
    if isinstance(outcome, CancelledElicitation):
        return Approval(False, "elicitation", True, None, RefusalCode.APPROVAL_DENIED,
                        "the human cancelled; nothing was done")
    return Approval(False, "not_required", required, None, RefusalCode.APPROVAL_INVALID,
                    "unrecognised approval outcome; nothing was done")


def client_decision(policy, action: str, required: bool, can_elicit: bool) -> ServerDecision | None:
    """No prompt needed (proceed), cannot prompt (the policy decides), or None: ask the human.
    Releasing the e-stop always needs a human, whatever `on_client_without_elicitation` says;
    under `approval.channel: url` the actions without a console page of their own are refused
    here already (`form_under_channel`), since their only question would be the form."""
    if not required:
        return ServerDecision(True, "not_required")
    console_only = None if action == "execute_plan" else _console_only(policy.approval, action)
    if can_elicit:
        return console_only
    if policy.approval.on_client_without_elicitation == "allow" and action != "reset_estop":
        return ServerDecision(True, "no_elicitation_client")
    return console_only or ServerDecision.refused(
        RefusalCode.APPROVAL_UNAVAILABLE,
        f"{action} needs a human's approval, but this MCP client cannot show approval prompts "
        "(no elicitation support) and the policy denies such requests. Use a client that supports "
        "elicitation.",
    )


#: leads the form's question when `approval.channel: url` lets the requester answer it itself
SELF_APPROVAL_NOTE = ("NOTE: approval.channel is url, but this question is asked in the requesting MCP client's own form, "
                      "because approval.allow_self_approval is on: whoever answers here approves their own request, "
                      "and the audit log records it as a self-approval.")


def _console_only(approval, action: str) -> ServerDecision | None:
    """The refusal of the form for `action` under `approval.channel: url` (None: the form may be
    asked). Why: the form is answered by the client that made the request; under `url` the
    policy wants a human in the operator console to decide, so the requester must not approve
    through its own form, unless `allow_self_approval` says it may."""
    if approval.channel != "url" or approval.allow_self_approval:
        return None
    if action == "execute_plan":
        how = ("this MCP client cannot open the console's link (it declares no URL-mode elicitation); use a client "
               "that does, so an operator approves the motion on its console page")
    elif action == "reset_estop":
        how = ("an operator releases the e-stop in the console: sign in with a human's operator token and type the "
               "event number on its Safety page")
    else:
        how = f"the console has no page to approve {action}, so it cannot be approved while the policy says url"
    return ServerDecision.refused(
        RefusalCode.APPROVAL_UNAVAILABLE,
        f"{action} needs a human's approval in the ArmWarden operator console (approval.channel: url), not in the "
        f"requesting client's own form, which would let the requester approve itself: {how}. Nothing was done.")


def form_under_channel(approval, action: str, prompt: Prompt) -> Prompt | ServerDecision:
    """The form's question for `action` as `approval.channel` allows it (`approval`: the policy's
    approval section): as is under `form` and `both`; under `url` refused, naming the console,
    or, with `allow_self_approval`, led by `SELF_APPROVAL_NOTE`."""
    if approval.channel != "url":
        return prompt
    refusal = _console_only(approval, action)
    if refusal is not None:
        return refusal
    return replace(prompt, message=f"{SELF_APPROVAL_NOTE}\n\n{prompt.message}")


def hold_to_channel(policy, approval: Approval) -> Approval:
    """The Guard's own check of where an answer came from: under `approval.channel: url` a
    granted form answer came from the requesting client itself, so it is refused, unless
    `allow_self_approval`, when it is marked self-approved (for the audit record)."""
    if not (approval.granted and approval.via == "elicitation" and policy.approval.channel == "url"):
        return approval
    if policy.approval.allow_self_approval:
        return replace(approval, self_approved=True)
    return Approval(False, "elicitation", approval.required, approval.operator, RefusalCode.APPROVAL_UNAVAILABLE,
                    "approval.channel is url: a human approves in the ArmWarden operator console, not in the "
                    "requesting client's own form; nothing was done")


def approval_required(policy, action: ApprovalAction, has_soft_violations: bool = False) -> bool:
    """Whether `action` needs a human, per `approval.mode` and `approval.require_for`."""
    approval = policy.approval
    if action == "reset_estop":
        return True  # releasing an e-stop always needs a human
    if action not in approval.require_for or approval.mode == "never":
        return False
    if approval.mode == "always":
        return True
    # outside_envelope: a plan inside the envelope runs without asking; the other actions have
    # no notion of "inside the envelope" and always ask
    return has_soft_violations if action == "execute" else True


def approval_code(digest: str) -> str:
    """A short code derived from a digest, shown in the prompt and the console to match them up."""
    short = hashlib.sha256(digest.encode()).hexdigest()[:8].upper()
    return f"{short[:4]}-{short[4:]}"


def quote_untrusted(text: object) -> str:
    """Model-written text, made safe to show a human: one line, quoted, truncated, labelled."""
    flat = flatten_reason(text, limit=UNTRUSTED_TEXT_LIMIT).replace('"', "'")
    return f'"{flat}" (written by the AI agent, unverified)'


def compose_prompt(title: str, facts: list[tuple[str, str]], warnings: list[str], untrusted: str | None = None) -> str:
    """The approval message: a title, the server's facts, warnings, then any model text."""
    lines = [title, ""]
    width = max((len(label) for label, _ in facts), default=0)
    lines += [f"{label:<{width}} : {value}" for label, value in facts]
    if warnings:
        lines += ["", "Warnings:"] + [f"  - {w}" for w in warnings]
    if untrusted is not None:
        lines += ["", f"Agent's note: {quote_untrusted(untrusted)}"]
    lines += ["", "Tick 'approve' only if you can see the robot and the motion is safe."]
    return "\n".join(lines)
