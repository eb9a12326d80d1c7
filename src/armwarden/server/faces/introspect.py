"""Faces of the introspect group: the robot's state, the limits, frames, controllers, the ROS
graph and the audit tail. Read-only: none of them changes anything."""

# no `from __future__ import annotations`: the SDK evaluates each face's annotations, which name
# this policy's bounds held in local variables
from typing import Annotated

from mcp_types import CallToolResult
from pydantic import Field, Strict

from armwarden.results import AuditTail, ControllerList, EnvelopeModel, GraphModel, RobotState, TransformResult
from armwarden.server.calls import ok, ok_data
from armwarden.server.faces.arguments import Name
from armwarden.server.faces.face import FaceContext, Faces


def introspect_faces(c: FaceContext) -> Faces:
    guard, faces = c.guard, Faces()
    robot = guard.robot

    @faces.add("Current joint positions [rad] and velocities, TCP pose [m, quaternion xyzw] in the base frame "
               f"{robot.base_frame}, estimated external wrench [N, N·m] and gripper state.")
    async def get_robot_state() -> Annotated[CallToolResult, RobotState]:
        return ok_data(await guard.robot_state_data())  # validated as RobotState by the SDK

    @faces.add("The limits the server enforces: joint limits, workspace box, keep-out zones, speed/step caps, force "
               "limits, gripper limits, allowlists and approval mode. Read this before planning.")
    async def get_safety_envelope() -> Annotated[CallToolResult, EnvelopeModel]:
        return ok(guard.safety_envelope(list(c.registered)))

    frames_hint = ", ".join(f for f in (robot.base_frame, robot.tcp_frame))

    @faces.add(f"Pose of source_frame expressed in target_frame at the current state (e.g. target_frame="
               f"{robot.base_frame}, source_frame={robot.tcp_frame}). Frames include {frames_hint} and every link of "
               "the robot description.")
    async def lookup_transform(target_frame: Name, source_frame: Name) -> Annotated[CallToolResult, TransformResult]:
        return ok(await guard.lookup_transform(target_frame, source_frame))

    @faces.add("Controllers with their type and state, and which ones the policy lets switch_controllers touch.")
    async def list_controllers() -> Annotated[CallToolResult, ControllerList]:
        return ok(await guard.list_controllers())

    @faces.add("Nodes, topics, services and actions visible to the backend.")
    async def list_ros_graph() -> Annotated[CallToolResult, GraphModel]:
        return ok(await guard.graph())

    @faces.add("The last n (1..100) audit-log records: tool calls, refusals, approvals, e-stops.")
    async def get_audit_tail(n: Annotated[int, Strict(), Field(ge=1, le=100)] = 20) -> Annotated[CallToolResult, AuditTail]:
        # in call order: the records of the calls answered before this one are in it
        return ok(AuditTail(records=await guard.audit.tail_async(n) if guard.audit is not None else []))

    return faces
