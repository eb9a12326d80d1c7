"""Faces of the gripper group: move, grasp and home the fingers, within the policy's width, speed
and force ranges (published in their schemas)."""

# no `from __future__ import annotations`: the SDK evaluates each face's annotations, which name
# this policy's bounds held in local variables
from typing import Annotated

from mcp_types import CallToolResult
from pydantic import Field

from armwarden.policy.devices import MIN_FINGER_SPEED_MPS
from armwarden.results import GripperResultModel
from armwarden.server.calls import ok
from armwarden.server.faces.arguments import Finite
from armwarden.server.faces.face import FaceContext, Faces


def gripper_faces(c: FaceContext) -> Faces:
    guard, faces = c.guard, Faces()
    cfg = c.policy.gripper
    assert cfg is not None  # the builder asks for the gripper's faces only with a gripper in the policy
    width = Field(ge=cfg.min_width_m, le=cfg.max_width_m, description=f"[m], {cfg.min_width_m:g}..{cfg.max_width_m:g}")
    speed = Field(ge=MIN_FINGER_SPEED_MPS, le=cfg.max_speed_mps,
                  description=f"[m/s], {MIN_FINGER_SPEED_MPS:g}..{cfg.max_speed_mps:g} (the default: the most)")
    epsilon = Field(ge=0.0, le=cfg.max_width_m, description="[m] tolerance on the grasp width")
    grasp_force = Field(gt=0.0, le=cfg.max_grasp_force_n, description=f"[N], at most {cfg.max_grasp_force_n:g}")

    @faces.add("Move the fingers to an opening width [m] without grasp force.")
    async def gripper_move(width_m: Annotated[Finite, width], speed_mps: Annotated[Finite | None, speed] = None,
                           ) -> Annotated[CallToolResult, GripperResultModel]:
        return ok(await guard.gripper("gripper_move", width_m=width_m, speed_mps=speed_mps))

    @faces.add("Close the fingers on an object of about width_m [m] with force_n [N].")
    async def gripper_grasp(
        width_m: Annotated[Finite, width], force_n: Annotated[Finite, grasp_force],
        speed_mps: Annotated[Finite | None, speed] = None,
        epsilon_inner_m: Annotated[Finite, epsilon] = 0.005, epsilon_outer_m: Annotated[Finite, epsilon] = 0.005,
    ) -> Annotated[CallToolResult, GripperResultModel]:
        return ok(await guard.gripper("gripper_grasp", width_m=width_m, force_n=force_n, speed_mps=speed_mps,
                                      epsilon_inner_m=epsilon_inner_m, epsilon_outer_m=epsilon_outer_m))

    @faces.add("Home the gripper (open fully and calibrate).")
    async def gripper_home() -> Annotated[CallToolResult, GripperResultModel]:
        return ok(await guard.gripper("gripper_home"))

    return faces
