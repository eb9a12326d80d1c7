"""The SDK's own floor (used by scripts/bench.py): an MCPServer with two constant tools and nothing
of ArmWarden behind them.

- `trivial`: a tiny structured result.
- `robot_state_shape`: a constant result with exactly `get_robot_state`'s model and published
  output schema, so the SDK's cost for that shape (serialising it, and the client re-validating
  it against the schema) is measured apart from what ArmWarden does to produce it.
"""

import sys
from pathlib import Path

from mcp.server.mcpserver import MCPServer
from pydantic import BaseModel

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src"))

from armwarden.results import RobotState
from armwarden.server.tools import inline_refs


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


def build() -> MCPServer:
    server = MCPServer("trivial")

    async def trivial() -> Trivial:
        return Trivial(values=[0.1] * 7, stamp=1.0)

    async def robot_state_shape() -> RobotState:
        return READY_STATE

    server.add_tool(trivial, name="trivial")
    server.add_tool(robot_state_shape, name="robot_state_shape")
    tool = server._tool_manager.get_tool("robot_state_shape")  # publish the schema ArmWarden publishes
    if tool is None or tool.output_schema is None:
        raise RuntimeError("the SDK registered robot_state_shape without an output schema")
    inlined = inline_refs(tool.output_schema)
    tool.output_schema.clear()
    tool.output_schema.update(inlined)
    return server


if __name__ == "__main__":
    build().run("stdio")
    sys.exit(0)
