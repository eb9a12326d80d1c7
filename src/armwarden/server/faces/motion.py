"""Faces of the motion group: three planners that never move, the one tool that moves the arm
(`execute_plan`, which asks a human where the policy says so), and the motion status.

Their schemas publish this policy's bounds: the joint count and limits, the scaling range, the
base frame, the length of a Cartesian path.
"""

# no `from __future__ import annotations`: the SDK evaluates each face's annotations, which name
# this policy's bounds held in local variables
from typing import Annotated, Any

import numpy as np
from mcp.server.mcpserver import AcceptedElicitation, Context
from mcp.server.mcpserver import Image as McpImage
from mcp_types import CallToolResult, InputRequiredResult
from pydantic import Field

from armwarden.approval.decision import ConsoleChannel, ServerDecision
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard import Prompt
from armwarden.planning.planners import MIN_SCALING, PoseTarget
from armwarden.results import ExecutionReport, MotionStatus, PlanSummary
from armwarden.server.approval import ApprovalAnswer, ResolvedByHand, ShownDigest, approval_parameters, can_elicit, uses_rounds
from armwarden.server.calls import ok
from armwarden.server.faces.arguments import JOINT_BOUND, MAX_WAYPOINTS, Finite, Orientation, Point, StrictBool, Waypoint, unit_rotation
from armwarden.server.faces.face import FaceContext, Faces
from armwarden.server.outofband import answer_out_of_band, answer_round, ask_round
from armwarden.server.roundstate import RoundSeal
from armwarden.tools import PlanKind


def motion_faces(c: FaceContext) -> Faces:
    guard, faces = c.guard, Faces()
    policy = c.policy
    robot = policy.robot
    n = len(robot.joint_names)
    limits_text = "; ".join(
        f"{name} [{robot.joint_limits[name].min:g}, {robot.joint_limits[name].max:g}]" for name in robot.joint_names
    )
    motion = policy.motion
    # the parameters' schema metadata depends on the policy (type checkers want the types spelled out
    # at each parameter; the metadata may be any value)
    scaling = Field(ge=MIN_SCALING, le=1.0,
                    description=f"Fraction of the joint limits in [{MIN_SCALING:g}, 1]; values above the policy cap "
                    f"are clamped to it (velocity cap {motion.max_velocity_scaling:g}, acceleration cap "
                    f"{motion.max_acceleration_scaling:g}); default from the policy")
    joints = Field(min_length=n, max_length=n, description=f"{n} joint positions [rad] in the order "
                   f"{list(robot.joint_names)}; limits: {limits_text}")
    frame = Field(default=None, max_length=128, description=f"Must be {robot.base_frame} (the default)")
    preview_png = Field(description="Attach a PNG preview (top and side views of the swept links against the "
                        "workspace and keep-out zones); about 3 ms of server time")

    async def planned(kind: PlanKind, request: dict[str, Any]) -> CallToolResult:
        summary, preview = await guard.plan(kind, request)
        extra = [McpImage(data=preview, format="png").to_image_content()] if preview else []
        return ok(summary, *extra, summary=f"{summary.status} {summary.plan_id}")

    def check_frame(frame_id: str | None) -> None:
        if frame_id not in (None, "", robot.base_frame):
            raise SafetyRefusal(RefusalCode.INVALID, f"frame_id must be the base frame {robot.base_frame!r}")

    @faces.add("Plan (does NOT move) a joint-space motion from the current state to joint_positions [rad]. Returns a plan "
               "summary with a single-use plan_id, the envelope's findings and a preview image. Only execute_plan moves "
               "the arm.")
    async def plan_to_joints(
        joint_positions: Annotated[list[Annotated[Finite, Field(ge=-JOINT_BOUND, le=JOINT_BOUND)]], joints],
        velocity_scaling: Annotated[Finite | None, scaling] = None,
        acceleration_scaling: Annotated[Finite | None, scaling] = None,
        preview: Annotated[StrictBool, preview_png] = True,
    ) -> Annotated[CallToolResult, PlanSummary]:
        return await planned("joints", {"joint_positions": np.array(joint_positions), "velocity_scaling": velocity_scaling,
                                        "acceleration_scaling": acceleration_scaling, "preview": preview})

    @faces.add(f"Plan (does NOT move) a motion that brings the TCP ({robot.tcp_frame}) to a pose in {robot.base_frame}: "
               "position [m] and optional orientation (unit quaternion xyzw; omitted = any). With free_yaw true the "
               "orientation may turn about the TCP's z axis (the tool axis keeps its direction, e.g. pointing down for a "
               "top-down grasp, and the planner picks how the fingers lie); default false: exactly that orientation. "
               "Uses IK, then a joint-space motion.")
    async def plan_to_pose(
        position: Point, orientation: Orientation | None = None, frame_id: Annotated[str | None, frame] = None,
        velocity_scaling: Annotated[Finite | None, scaling] = None,
        acceleration_scaling: Annotated[Finite | None, scaling] = None,
        preview: Annotated[StrictBool, preview_png] = True,
        free_yaw: Annotated[StrictBool, Field(description="With orientation: any rotation about the TCP's z axis "
                                              "is acceptable (default false)")] = False,
    ) -> Annotated[CallToolResult, PlanSummary]:
        check_frame(frame_id)
        target = PoseTarget(np.array([position.x, position.y, position.z]), unit_rotation(orientation), free_yaw)
        return await planned("pose", {"target": target, "velocity_scaling": velocity_scaling,
                                      "acceleration_scaling": acceleration_scaling, "preview": preview})

    @faces.add(f"Plan (does NOT move) straight TCP lines through 1..{MAX_WAYPOINTS} waypoints [m] in {robot.base_frame}, "
               "stopping at each; orientation is interpolated. The whole TCP path may be at most "
               f"{motion.max_cartesian_step_m:g} m.")
    async def plan_cartesian_path(
        waypoints: Annotated[list[Waypoint], Field(min_length=1, max_length=MAX_WAYPOINTS)],
        frame_id: Annotated[str | None, frame] = None,
        velocity_scaling: Annotated[Finite | None, scaling] = None,
        acceleration_scaling: Annotated[Finite | None, scaling] = None,
        preview: Annotated[StrictBool, preview_png] = True,
    ) -> Annotated[CallToolResult, PlanSummary]:
        check_frame(frame_id)
        targets = [PoseTarget(np.array([w.position.x, w.position.y, w.position.z]), unit_rotation(w.orientation))
                   for w in waypoints]
        return await planned("cartesian", {"waypoints": targets, "velocity_scaling": velocity_scaling,
                                           "acceleration_scaling": acceleration_scaling, "preview": preview})

    async def precheck_execute(ctx: Context, plan_id: str) -> ServerDecision | Prompt:
        return await guard.precheck_execute(plan_id, can_elicit(ctx))

    # execute_plan resolves its approval by hand (no `Resolve` parameters): under 2026-07-28 the
    # console channel asks in an InputRequiredResult of its own (`server.outofband`)
    resolve_approval = ResolvedByHand(approval_parameters(precheck_execute, policy.approval, "execute_plan", console=True),
                                      {"plan_id"})
    seal = RoundSeal()

    async def execute(plan_id: str, ctx: Context, approval: ApprovalAnswer, shown: ShownDigest,
                      outcome: Any) -> CallToolResult:
        async def progress(fraction: float) -> None:
            await ctx.report_progress(fraction, 1.0, "moving")

        asked: object = approval.data if isinstance(approval, AcceptedElicitation) else None
        if isinstance(asked, ConsoleChannel) and outcome is None:  # url | both: the console's record decides
            outcome = (await answer_round(ctx, guard, asked, plan_id, seal) if uses_rounds(ctx)
                       else await answer_out_of_band(ctx, guard, asked, plan_id))
        report = await guard.execute(plan_id, approval if outcome is None else outcome, shown, progress)
        return ok(report, summary=f"{report.status}: {report.detail}")

    @faces.add("EXECUTE a previously planned motion on the robot (the only tool that moves the arm). The "
               "server re-checks the plan, may ask a human to approve, watches the contact force while "
               "moving and streams progress. Each plan_id runs at most once.", answers_itself=True)
    async def execute_plan(
        plan_id: Annotated[str, Field(min_length=1, max_length=64, description="The plan_id from a plan_* result")],
        ctx: Context,
    ) -> Annotated[CallToolResult, ExecutionReport] | InputRequiredResult:
        resolved = await resolve_approval(ctx, plan_id=plan_id)
        if isinstance(resolved, InputRequiredResult):
            return resolved  # the SDK's form question: a question round, not admitted (nothing ran)
        approval, shown = resolved
        asked: object = approval.data if isinstance(approval, AcceptedElicitation) else None
        outcome: Any = None
        if isinstance(asked, ConsoleChannel) and uses_rounds(ctx) and ctx.request_state is None:
            outcome = ask_round(ctx, guard, asked, plan_id, seal)
            if isinstance(outcome, InputRequiredResult):
                return outcome  # the console link (and form): a question round, not admitted
        return await c.answer("execute_plan", lambda: execute(plan_id, ctx, approval, shown, outcome))

    @faces.add("The summary of a plan you made and have not run (status, findings, whether a human will be asked, "
               "expiry), as its plan_* call returned it, without the preview. Refused for a plan that was used, "
               "expired, made before the latest e-stop or by another client.")
    async def get_plan(
        plan_id: Annotated[str, Field(min_length=1, max_length=64, description="The plan_id from a plan_* result")],
    ) -> Annotated[CallToolResult, PlanSummary]:
        return ok(guard.plan_summary(plan_id))

    @faces.add("Whether a plan is executing, its progress (0..1) and the last execution result.")
    async def get_motion_status() -> Annotated[CallToolResult, MotionStatus]:
        return ok(guard.motion_status())

    return faces
