"""The order in which the Guard's flows say no, as data.

Each tool that changes the robot passes a fixed sequence of gates; the first that fails refuses
the call and nothing after it runs. The flows (`gripper`, `actions`, `planning`, and the Guard's
own `execute` and `reset_estop`) are written in this order; `tests/guard/test_gate_order.py`
breaks every combination of a flow's gates and checks that the refusal is the first broken gate's,
and `docs/tools.md` prints each tool's sequence from here. The rate limit comes first for every
tool (`ToolBuilder.answer`, before the flow runs); stopping tools pass no gate at all.
"""

from __future__ import annotations

from dataclasses import dataclass

from armwarden.core.errors import RefusalCode


@dataclass(frozen=True)
class Gate:
    """One check and what it answers when it says no."""

    name: str
    refuses: tuple[RefusalCode, ...]


RATE_LIMIT = Gate("rate limit", (RefusalCode.RATE_LIMITED,))
AUDIT_WRITABLE = Gate("audit log writable", (RefusalCode.AUDIT_UNAVAILABLE,))
NOT_ESTOPPED = Gate("e-stop not latched", (RefusalCode.ESTOPPED,))
GRIPPER_ARGUMENTS = Gate("arguments within the policy's gripper section",
                         (RefusalCode.OUT_OF_RANGE, RefusalCode.NOT_CONFIGURED, RefusalCode.INVALID))
ACTION_ARGUMENTS = Gate("arguments within the policy (allowlist, caps)",
                        (RefusalCode.OUT_OF_RANGE, RefusalCode.NOT_ALLOWED, RefusalCode.INVALID))
ONE_GRIPPER_ACTION = Gate("no other gripper action running", (RefusalCode.BUSY,))
ONE_EXECUTION = Gate("no other plan executing", (RefusalCode.BUSY,))
APPROVED = Gate("approval granted where the policy requires it",
                (RefusalCode.APPROVAL_DENIED, RefusalCode.APPROVAL_UNAVAILABLE, RefusalCode.APPROVAL_INVALID))
APPROVED_THIS_REQUEST = Gate("the approval was given for this very request", (RefusalCode.APPROVAL_MISMATCH,))
FRESH_STATE = Gate("fresh joint state", (RefusalCode.STALE_STATE, RefusalCode.NO_STATE))
NO_ESTOP_WHILE_PLANNING = Gate("no e-stop while planning", (RefusalCode.ESTOPPED,))
PLAN_USABLE = Gate("the plan exists, is this caller's, unexpired, unused, made since the last e-stop",
                   (RefusalCode.UNKNOWN_PLAN, RefusalCode.NOT_PLAN_OWNER, RefusalCode.EXPIRED_PLAN, RefusalCode.USED_PLAN,
                    RefusalCode.INVALIDATED_PLAN, RefusalCode.REJECTED_PLAN))
NO_STOP_WHILE_DECIDING = Gate("no stop while a human decided", (RefusalCode.STOPPED,))
ENVELOPE_RECHECK = Gate("the envelope passes the plan again", (RefusalCode.ENVELOPE,))
ARM_AT_START = Gate("the arm is still where the plan starts", (RefusalCode.STALE_PLAN, RefusalCode.STALE_STATE))
FORCE_MONITOR = Gate("a usable wrench and no contact before moving", (RefusalCode.NO_WRENCH, RefusalCode.IN_CONTACT))
NO_STOP_SINCE_CLAIMED = Gate("no stop or e-stop since the slot was claimed", (RefusalCode.STOPPED,))
RELEASE_RECORDED = Gate("the release is recorded, for the event shown, while it is the one latched",
                        (RefusalCode.AUDIT_UNAVAILABLE, RefusalCode.RESET_REFUSED, RefusalCode.NOT_ESTOPPED))

GRIPPER = (RATE_LIMIT, AUDIT_WRITABLE, NOT_ESTOPPED, GRIPPER_ARGUMENTS, ONE_GRIPPER_ACTION)
CONTROL_ACTION = (RATE_LIMIT, ACTION_ARGUMENTS, AUDIT_WRITABLE, NOT_ESTOPPED, APPROVED, APPROVED_THIS_REQUEST)
PLANNING = (RATE_LIMIT, NOT_ESTOPPED, FRESH_STATE, NO_ESTOP_WHILE_PLANNING)
EXECUTION = (RATE_LIMIT, AUDIT_WRITABLE, ONE_EXECUTION, PLAN_USABLE, APPROVED, NO_STOP_WHILE_DECIDING,
             APPROVED_THIS_REQUEST, NOT_ESTOPPED, ENVELOPE_RECHECK, ARM_AT_START, FORCE_MONITOR, NO_STOP_SINCE_CLAIMED)
RESET = (RATE_LIMIT, APPROVED, RELEASE_RECORDED)

#: each tool whose flow has gates → its gates in order
GATES: dict[str, tuple[Gate, ...]] = {
    "plan_to_joints": PLANNING,
    "plan_to_pose": PLANNING,
    "plan_cartesian_path": PLANNING,
    "execute_plan": EXECUTION,
    "gripper_move": GRIPPER,
    "gripper_grasp": GRIPPER,
    "gripper_home": GRIPPER,
    "switch_controllers": CONTROL_ACTION,
    "set_collision_thresholds": CONTROL_ACTION,
    "error_recovery": CONTROL_ACTION,
    "reset_estop": RESET,
}


def first_refusal(gates: tuple[Gate, ...], broken: set[Gate]) -> Gate | None:
    """Which gate refuses when the gates in `broken` would each say no (None: none does)."""
    return next((gate for gate in gates if gate in broken), None)


__all__ = ["GATES", "Gate", "first_refusal"]
