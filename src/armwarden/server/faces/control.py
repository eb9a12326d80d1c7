"""Faces of the control group: switch allowlisted controllers, set the robot's collision
thresholds. Both change the robot and may be put behind a human's approval."""

# no `from __future__ import annotations`: the SDK evaluates each face's annotations, which name
# this policy's bounds held in local variables
from typing import Annotated

from mcp.server.mcpserver import Context
from mcp_types import CallToolResult
from pydantic import Field

from armwarden.approval.decision import ServerDecision
from armwarden.guard import Prompt
from armwarden.results import ActionResult
from armwarden.server.approval import ApprovalAnswer, ShownDigest, approval_parameters, can_elicit
from armwarden.server.calls import ok
from armwarden.server.faces.arguments import Finite, Name
from armwarden.server.faces.face import FaceContext, Faces


def control_faces(c: FaceContext) -> Faces:
    guard, faces = c.guard, Faces()
    force = c.policy.force
    names = Field(default_factory=list, max_length=16)
    contact_force = Field(gt=0.0, le=force.max_contact_force_n, description=f"[N], at most {force.max_contact_force_n:g}")
    contact_torque = Field(gt=0.0, le=force.max_contact_torque_nm,
                           description=f"[N·m], at most {force.max_contact_torque_nm:g}")

    async def precheck_switch(ctx: Context, activate: list[str], deactivate: list[str]) -> ServerDecision | Prompt:
        return guard.precheck_action("switch_controllers", can_elicit(ctx), activate=activate, deactivate=deactivate)

    switch_gate = approval_parameters(precheck_switch, c.policy.approval, "switch_controllers")

    @faces.add("Activate/deactivate controllers named in the policy's allowlist: "
               f"{list(c.policy.controllers.allowlist)}.")
    async def switch_controllers(
        approval: Annotated[ApprovalAnswer, switch_gate.approval], shown: Annotated[ShownDigest, switch_gate.shown],
        activate: Annotated[list[Name], names], deactivate: Annotated[list[Name], names],
    ) -> Annotated[CallToolResult, ActionResult]:
        return ok(await guard.run_action("switch_controllers", approval, shown, activate=activate, deactivate=deactivate))

    async def precheck_thresholds(ctx: Context, force_n: float, torque_nm: float) -> ServerDecision | Prompt:
        return guard.precheck_action("set_collision_thresholds", can_elicit(ctx), force_n=force_n, torque_nm=torque_nm)

    thresholds_gate = approval_parameters(precheck_thresholds, c.policy.approval, "set_collision_thresholds")

    @faces.add("Set the robot's collision (reflex) thresholds, at most the policy's contact force/torque limits.")
    async def set_collision_thresholds(
        force_n: Annotated[Finite, contact_force], torque_nm: Annotated[Finite, contact_torque],
        approval: Annotated[ApprovalAnswer, thresholds_gate.approval],
        shown: Annotated[ShownDigest, thresholds_gate.shown],
    ) -> Annotated[CallToolResult, ActionResult]:
        return ok(await guard.run_action("set_collision_thresholds", approval, shown, force_n=force_n, torque_nm=torque_nm))

    return faces
