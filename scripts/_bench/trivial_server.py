"""The SDK's own floor: an MCPServer with one trivial structured tool (used by scripts/bench.py)."""

import sys

from mcp.server.mcpserver import MCPServer
from pydantic import BaseModel


class Trivial(BaseModel):
    values: list[float]
    stamp: float


def build() -> MCPServer:
    server = MCPServer("trivial")

    async def trivial() -> Trivial:
        return Trivial(values=[0.1] * 7, stamp=1.0)

    server.add_tool(trivial, name="trivial")
    return server


if __name__ == "__main__":
    build().run("stdio")
    sys.exit(0)
