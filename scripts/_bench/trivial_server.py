"""The SDK's own floor (used by scripts/bench.py): an MCPServer with constant tools and nothing
of ArmWarden behind them.

- `trivial`: a tiny structured result.
- `robot_state_shape`: a constant result with exactly `get_robot_state`'s model and published
  output schema, so the SDK's cost for that shape (serialising it, and the client re-validating
  it against the schema) is measured apart from what ArmWarden does to produce it.
- with `shapes` (a JSON file of results ArmWarden really returned, written by the benchmark):
  `get_safety_status_shape`, `estop_shape`, `plan_to_pose_shape` and
  `plan_to_pose_preview_shape` (the same summary plus the same PNG, as image content), each
  with the model and output schema of the ArmWarden tool it stands for.

Run as a script: `trivial_server.py [--shapes FILE] [--http PORT | --armwarden-stdio]` serves
stdio with the SDK's transport, streamable HTTP on 127.0.0.1:PORT (the SDK's defaults: stateful
sessions, SSE responses, as ArmWarden), or stdio through ArmWarden's own stdio transport
(`armwarden.transport.stdio`: its gate, and pipes served from the event loop), so ArmWarden's
tools can be measured apart from its transport.
"""

import argparse
import json
import sys
from pathlib import Path
from typing import Annotated, Any

from mcp.server.mcpserver import MCPServer
from mcp_types import CallToolResult, ImageContent, TextContent
from pydantic import BaseModel

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src"))

from armwarden.results import EStopResult, PlanSummary, RobotState, SafetyStatus
from armwarden.server.registration import inline_refs


class Trivial(BaseModel):
    values: list[float]
    stamp: float


READY_STATE = RobotState.model_validate({
    "joint_names": [f"fr3_joint{i}" for i in range(1, 8)],
    "joint_positions": [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398],
    "joint_velocities": [0.0] * 7,
    "tcp_pose": {"position": {"x": 0.306891, "y": 0.0, "z": 0.486882},
                 "orientation": {"x": 1.0, "y": 0.0, "z": 0.0, "w": 0.0}},
    "frame_id": "fr3_link0",
    "wrench": {"force": {"x": 0.0, "y": 0.0, "z": 0.0}, "torque": {"x": 0.0, "y": 0.0, "z": 0.0}},
    "gripper": {"width_m": 0.08, "is_grasped": False, "moving": False},
    "stamp": 1.0,
})


def _constant(model: type[BaseModel], structured: dict[str, Any], image_b64: str | None = None):
    """A tool body returning a fixed result of `model` as ArmWarden's tools do (`server.calls.ok`):
    the model's JSON as text, its structured content, and optionally one PNG."""
    value = model.model_validate(structured)

    async def body() -> Annotated[CallToolResult, model]:  # type: ignore[valid-type]
        extra = [ImageContent(type="image", data=image_b64, mime_type="image/png")] if image_b64 else []
        return CallToolResult(content=[TextContent(type="text", text=value.model_dump_json()), *extra],
                              structured_content=value.model_dump(mode="json"))

    return body


def _publish_inlined_schema(server: MCPServer, name: str) -> None:
    tool = server._tool_manager.get_tool(name)  # publish the schema ArmWarden publishes
    if tool is None or tool.output_schema is None:
        raise RuntimeError(f"the SDK registered {name} without an output schema")
    inlined = inline_refs(tool.output_schema)
    tool.output_schema.clear()
    tool.output_schema.update(inlined)


def build(shapes: dict[str, Any] | None = None) -> MCPServer:
    server = MCPServer("trivial")

    async def trivial() -> Trivial:
        return Trivial(values=[0.1] * 7, stamp=1.0)

    async def robot_state_shape() -> RobotState:
        return READY_STATE

    server.add_tool(trivial, name="trivial")
    server.add_tool(robot_state_shape, name="robot_state_shape")
    _publish_inlined_schema(server, "robot_state_shape")
    if shapes:
        for name, body in (
            ("get_safety_status_shape", _constant(SafetyStatus, shapes["get_safety_status"])),
            ("estop_shape", _constant(EStopResult, shapes["estop"])),
            ("plan_to_pose_shape", _constant(PlanSummary, shapes["plan_to_pose"])),
            ("plan_to_pose_preview_shape", _constant(PlanSummary, shapes["plan_to_pose"], shapes["preview_png_b64"])),
        ):
            server.add_tool(body, name=name)
            _publish_inlined_schema(server, name)
    return server


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--shapes", default=None)
    parser.add_argument("--http", type=int, default=None, metavar="PORT")
    parser.add_argument("--armwarden-stdio", action="store_true",
                        help="serve stdio through ArmWarden's stdio transport instead of the SDK's")
    args = parser.parse_args()
    floor = build(json.loads(Path(args.shapes).read_text()) if args.shapes else None)
    if args.http is None and args.armwarden_stdio:
        import anyio

        from armwarden.transport.stdio import serve_stdio

        anyio.run(serve_stdio, floor)
    elif args.http is None:
        floor.run("stdio")
    else:
        import anyio

        anyio.run(lambda: floor.run_streamable_http_async(host="127.0.0.1", port=args.http))
    sys.exit(0)
