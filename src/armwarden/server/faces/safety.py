"""Faces of the safety group, registered whatever the policy enables: stop, e-stop, release the
e-stop (always a human's decision), clear a robot error, and the safety status."""

# no `from __future__ import annotations`: the SDK evaluates each face's annotations, which name
# this policy's bounds held in local variables
from typing import Annotated, Any

from mcp.server.mcpserver import Context
from mcp_types import CallToolResult

from armwarden.approval.decision import ServerDecision
from armwarden.guard import Prompt
from armwarden.results import ActionResult, EStopResult, ResetResult, SafetyStatus, StopResult
from armwarden.server.approval import ApprovalAnswer, ShownDigest, approval_parameters, can_elicit
from armwarden.server.calls import ok
from armwarden.server.faces.face import FaceContext, Faces


def safety_faces(c: FaceContext) -> Faces:
    guard, faces = c.guard, Faces()

    @faces.add("Stop the current motion now: the arm trajectory and any gripper action. Never rate limited, never needs "
               "approval.")
    async def stop_motion() -> Annotated[CallToolResult, StopResult]:
        return ok(await guard.stop_motion())

    @faces.add("SOFTWARE E-STOP: stop all motion (arm and gripper), invalidate every plan and refuse motion, gripper and "
               "control tools until a human approves reset_estop. Accepts any reason. Not a substitute for the hardware "
               "e-stop.")
    async def estop(reason: Any = None) -> Annotated[CallToolResult, EStopResult]:
        result = await guard.emergency_stop(reason, source="estop")
        return ok(result, summary=f"e-stop #{result.estop_event.number}")

    def precheck_reset(ctx: Context) -> ServerDecision | Prompt:
        return guard.precheck_reset(can_elicit(ctx))

    reset_gate = approval_parameters(precheck_reset, c.policy.approval, "reset_estop")

    @faces.add("Release the software e-stop (and a latched force violation). Always asks a human, who approves the "
               "specific e-stop event they were shown.")
    async def reset_estop(approval: Annotated[ApprovalAnswer, reset_gate.approval],
                          shown: Annotated[ShownDigest, reset_gate.shown]) -> Annotated[CallToolResult, ResetResult]:
        return ok(await guard.reset_estop(approval, shown))

    async def precheck_recovery(ctx: Context) -> ServerDecision | Prompt:
        return guard.precheck_action("error_recovery", can_elicit(ctx))

    recovery_gate = approval_parameters(precheck_recovery, c.policy.approval, "error_recovery")

    @faces.add("Clear the robot's error/reflex state (e.g. after a collision reflex). Refused while the e-stop is "
               "latched.")
    async def error_recovery(
        approval: Annotated[ApprovalAnswer, recovery_gate.approval], shown: Annotated[ShownDigest, recovery_gate.shown],
    ) -> Annotated[CallToolResult, ActionResult]:
        return ok(await guard.run_action("error_recovery", approval, shown))

    @faces.add("E-stop state and event, latched force violation, dry-run flag, the last envelope violation, backend "
               "faults and whether the audit log can be written. Never rate limited.")
    async def get_safety_status() -> Annotated[CallToolResult, SafetyStatus]:
        return ok(guard.safety_status())

    return faces
