"""The approvable control actions besides motion: switch_controllers, set_collision_thresholds,
error_recovery. Each is described once here (`control_action`: argument check, approval prompt,
backend command, what to report), and `ControlActions` runs them all through the same steps:

- pre-check (the approval resolver; reads only): arguments → rate limit → e-stop latch → whether
  a human must and can be asked → the prompt;
- run (the tool body): arguments → audit writable → e-stop latch → approval (granted, and given
  for this very request: the prompt's digest) → the approval is spent → dry run → the backend.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal

from armwarden.approval import prompts
from armwarden.approval.decision import Prompt, ServerDecision, approval_required, client_decision
from armwarden.backends.base import Backend
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard.gates import GuardState
from armwarden.policy import Policy
from armwarden.results import ActionResult
from armwarden.safety import checks

ControlTool = Literal["switch_controllers", "set_collision_thresholds", "error_recovery"]


@dataclass(frozen=True)
class ControlAction:
    """One approvable control action with its arguments bound."""

    check: Callable[[], None]  # raises SafetyRefusal for arguments outside the policy
    prompt: Callable[[], Prompt]  # what the human is asked, and the digest the answer is bound to
    actuate: Callable[[int], Awaitable[Any]]  # the backend command, given the stop epoch it was decided under
    done: str  # what the result says was done


def control_action(tool: ControlTool, arguments: dict[str, Any], *, policy: Policy, backend: Backend, round_: str,
                   faults: list[str], dry_run: bool) -> ControlAction:
    """`round_` is the action round (`ControlActions.round`)."""
    if tool == "switch_controllers":
        on, off = arguments["activate"], arguments["deactivate"]
        return ControlAction(lambda: checks.check_controllers(policy, on, off),
                             lambda: prompts.switch_prompt(round_, on, off, dry_run),
                             lambda epoch: backend.switch_controllers(on, off, stop_epoch=epoch),
                             f"activated {on or 'none'}, deactivated {off or 'none'}")
    if tool == "set_collision_thresholds":
        force_n, torque_nm = arguments["force_n"], arguments["torque_nm"]
        return ControlAction(lambda: checks.check_thresholds(policy, force_n, torque_nm),
                             lambda: prompts.thresholds_prompt(round_, policy, force_n, torque_nm),
                             lambda epoch: backend.set_collision_thresholds(force_n, torque_nm, stop_epoch=epoch),
                             f"collision thresholds set to {force_n:g} N / {torque_nm:g} N·m")

    async def recover(epoch: int) -> None:
        await backend.error_recovery(stop_epoch=epoch)
        faults.clear()

    return ControlAction(lambda: None, lambda: prompts.recovery_prompt(round_, faults), recover, "error recovery done")


class ControlActions:
    """The control-action flow, through the Guard's gates. Counts the completed actions per tool
    (see `round`)."""

    def __init__(self, state: GuardState) -> None:
        self._state = state
        self._done: dict[str, int] = {}

    def round(self, tool: str) -> str:
        """Part of every action's approval digest and prompt: it changes after each completed action
        of `tool`, with each e-stop and with each stop, so an approval (or a replayed protocol round
        carrying one) never carries over to a later request, across an e-stop and its reset, or
        past a stop pressed while a human decided."""
        return f"{self._state.latch.generation}.{self._state.stopper.generation}.{self._done.get(tool, 0)}"

    def _bind(self, tool: ControlTool, arguments: dict[str, Any]) -> ControlAction:
        state = self._state
        return control_action(tool, arguments, policy=state.policy, backend=state.backend, round_=self.round(tool),
                              faults=state.faults, dry_run=state.dry_run)

    def precheck(self, tool: ControlTool, can_elicit: bool, arguments: dict[str, Any]) -> ServerDecision | Prompt:
        """Everything that would refuse `tool`, checked before any human is asked. Read-only."""
        state = self._state
        action = self._bind(tool, arguments)
        try:  # never ask a human to approve a request that would be refused anyway
            action.check()
        except SafetyRefusal as exc:
            return ServerDecision.refusal(exc)
        if (d := state.peek_rate(tool)) is not None:
            return d
        if (r := state.estop_refusal(tool)) is not None:
            return ServerDecision.refusal(r)
        decision = client_decision(state.policy, tool, approval_required(state.policy, tool), can_elicit)
        return decision if decision is not None else action.prompt()

    async def run(self, tool: ControlTool, approval_outcome: Any, shown: str | None, arguments: dict[str, Any]) -> ActionResult:
        state = self._state
        action = self._bind(tool, arguments)
        action.check()
        state.require_audit(tool)
        stop_epoch = state.backend.stop_epoch  # decided now: a stop from here on keeps it from starting ...
        state.require_not_estopped(tool)  # ... and an e-stop latched before it refuses
        approval = state.interpret_approval(approval_outcome, approval_required(state.policy, tool))
        if not approval.granted:
            raise approval.refusal(tool)
        if approval.via == "elicitation" and shown != action.prompt().digest:
            raise SafetyRefusal(RefusalCode.APPROVAL_MISMATCH,
                                f"{tool}: the approval was given for a different request; nothing was done")
        self._done[tool] = self._done.get(tool, 0) + 1  # this approval is now spent
        if state.dry_run:
            return ActionResult(status="dry_run", approval=approval.info(), detail=f"dry run: {action.done} would be done; nothing changed")
        await state.readings.backend_call(tool.replace("_", " "), action.actuate(stop_epoch))
        return ActionResult(status="succeeded", approval=approval.info(), detail=action.done)
