"""The Guard's shared safety state, and the gates every flow runs over it.

One record (`GuardState`) holds what the flows share: the policy, the backend and its readings,
the rate limiter, the e-stop latch, the plan store, the stopper, the audit log, and the last
violation and result the status tools report. Each gate is a named method that refuses with a
`SafetyRefusal` (or, for an approval resolver's read-only pre-check, returns the refusal): the
flows (`planning`, `gripper`, `actions`, and the Guard's own `execute`) run them in their order
and hold this record, not the Guard, so they are peers of one another.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from armwarden.approval.decision import Approval, ServerDecision, hold_to_channel, interpret
from armwarden.approval.plans import PlanStore
from armwarden.audit import AuditLog
from armwarden.backends.base import Backend
from armwarden.callcontext import current_call, note_approval
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard.readings import Readings
from armwarden.guard.stopping import Stopper
from armwarden.policy import Policy
from armwarden.preflight import RuntimeModel
from armwarden.results import ExecutionReport
from armwarden.safety.estop import EStopLatch
from armwarden.safety.ratelimit import RateLimiter
from armwarden.safety.violations import Violation


@dataclass(eq=False)
class GuardState:
    """What the Guard's flows share (see the module docstring)."""

    policy: Policy
    #: the planning model, used on the planning thread only (its envelope decides)
    planning: RuntimeModel
    backend: Backend
    readings: Readings
    limiter: RateLimiter
    latch: EStopLatch
    plans: PlanStore
    stopper: Stopper
    audit: AuditLog | None
    #: the last hard (or soft) finding of a plan or a re-validation, for `get_safety_status`
    last_violation: Violation | None = None
    #: the last execution's report, for `get_motion_status`
    last_result: ExecutionReport | None = None

    @property
    def dry_run(self) -> bool:
        return self.policy.dry_run

    @property
    def faults(self) -> list[str]:
        """One list: stops, the audit writer and error recovery add to it."""
        return self.stopper.faults

    # ------------------------------------------------------------------ gates
    def admit(self, tool: str) -> None:
        """Rate limit (exempt tools always pass). Raises RATE_LIMITED."""
        decision = self.limiter.try_acquire(tool)
        if not decision.allowed:
            raise SafetyRefusal(RefusalCode.RATE_LIMITED, decision.message)

    def charge(self, tool: str) -> None:
        """Take a rate token for a call refused before its body ran (bad arguments): floods of
        invalid calls still cost tokens."""
        self.limiter.try_acquire(tool)

    def peek_rate(self, tool: str) -> ServerDecision | None:
        """The rate limit's answer without taking a token (approval resolvers may run twice)."""
        decision = self.limiter.peek(tool)
        return None if decision.allowed else ServerDecision.refused(RefusalCode.RATE_LIMITED, decision.message)

    def estop_refusal(self, what: str) -> SafetyRefusal | None:
        event = self.latch.current_event
        if event is None:
            return None
        return SafetyRefusal(RefusalCode.ESTOPPED, f"{what} refused: the software e-stop #{event.number} is latched "
                             f"({event.source}: {event.reason}). A human must approve reset_estop before anything can "
                             "move again.")

    def require_not_estopped(self, what: str) -> None:
        if (refusal := self.estop_refusal(what)) is not None:
            raise refusal

    def audit_unusable(self) -> str | None:
        """Why the audit log cannot be written now (None while it can, or when there is no log)."""
        return None if self.audit is None else self.audit.unusable

    def require_audit(self, what: str) -> None:
        """Nothing actuates unless it can be audited: a log that failed a write refuses, and so do we."""
        if (why := self.audit_unusable()) is not None:
            raise SafetyRefusal(RefusalCode.AUDIT_UNAVAILABLE, f"{what} refused: the audit log cannot be written "
                                f"({why}); nothing moves until it is repaired and the daemon restarted")

    def interpret_approval(self, outcome: Any, required: bool) -> Approval:
        """The resolver's outcome as an Approval, noted on the call's audit record. Under
        `approval.channel: url` a form answer is the requester's own (`hold_to_channel`)."""
        approval = hold_to_channel(self.policy, interpret(outcome, required))
        note_approval(approval.granted, approval.via, approval.operator, type(outcome).__name__)
        if approval.self_approved and (call := current_call()) is not None:
            call.extra["approval"]["self_approval"] = True  # the approver was the requester (policy allows it)
        return approval


__all__ = ["GuardState"]
