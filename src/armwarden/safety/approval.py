"""Human approval: when it is needed, what the human is shown, and what their answer means.

The prompt leads with facts the server computed (durations, speeds against caps, the approval
code derived from the plan digest); anything the model wrote is shown on one line, quoted,
truncated and labelled unverified, so an injected "operator note: safe to approve" cannot pass
for server text. The form's `approve` box is unticked by default: only an explicit tick runs.

This module is pure: the MCP resolvers that use it must stay side-effect free (under protocol
2026-07-28 they may run more than once per call).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool

from armwarden.errors import SafetyRefusal
from armwarden.safety.estop import flatten_reason

Action = Literal["execute", "switch_controllers", "reset_estop", "error_recovery", "set_collision_thresholds"]
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
    code: str = ""
    message: str = ""

    @classmethod
    def refusal(cls, refused: SafetyRefusal) -> ServerDecision:
        """The decision a pre-check returns for a refusal the Guard raised (or would raise)."""
        return cls(False, "refused", refused.code, str(refused))


def approval_required(policy, action: Action, has_soft_violations: bool = False) -> bool:
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
