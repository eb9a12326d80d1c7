"""The approvable control actions besides motion: switch_controllers, set_collision_thresholds,
error_recovery. Each is described once here (argument check, approval prompt, backend command,
what to report); the Guard runs them all through the same admission and approval steps.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal

from armwarden.backends.base import Backend
from armwarden.policy import Policy
from armwarden.safety import checks, prompts
from armwarden.safety.approval import Prompt

ControlTool = Literal["switch_controllers", "set_collision_thresholds", "error_recovery"]


@dataclass(frozen=True)
class ControlAction:
    """One approvable control action with its arguments bound."""

    check: Callable[[], None]  # raises SafetyRefusal for arguments outside the policy
    prompt: Callable[[], Prompt]  # what the human is asked, and the digest the answer is bound to
    actuate: Callable[[], Awaitable[Any]]  # the backend command
    done: str  # what the result says was done


def control_action(tool: ControlTool, arguments: dict[str, Any], *, policy: Policy, backend: Backend, round_: str,
                   faults: list[str], dry_run: bool) -> ControlAction:
    """`round_` is the Guard's action round (it changes after every completed action and e-stop)."""
    if tool == "switch_controllers":
        on, off = arguments["activate"], arguments["deactivate"]
        return ControlAction(lambda: checks.check_controllers(policy, on, off),
                             lambda: prompts.switch_prompt(round_, on, off, dry_run),
                             lambda: backend.switch_controllers(on, off),
                             f"activated {on or 'none'}, deactivated {off or 'none'}")
    if tool == "set_collision_thresholds":
        force_n, torque_nm = arguments["force_n"], arguments["torque_nm"]
        return ControlAction(lambda: checks.check_thresholds(policy, force_n, torque_nm),
                             lambda: prompts.thresholds_prompt(round_, policy, force_n, torque_nm),
                             lambda: backend.set_collision_thresholds(force_n, torque_nm),
                             f"collision thresholds set to {force_n:g} N / {torque_nm:g} N·m")

    async def recover() -> None:
        await backend.error_recovery()
        faults.clear()

    return ControlAction(lambda: None, lambda: prompts.recovery_prompt(round_, faults), recover, "error recovery done")
