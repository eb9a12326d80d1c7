"""The tool catalogue: one frozen record per MCP tool, and every tool-name set derived from it.

A low layer on purpose: the policy (tool groups, approvable actions), the transports (stopping
tools, the observer role), the counting backend and the server all read these records, so none
of them keeps its own list of names. Adding a tool starts here (docs/add-a-tool.md).
"""

from armwarden.tools.registry import TOOLS, names, spec_of, specs
from armwarden.tools.spec import ApprovalAction, Hints, PlanKind, ToolGroup, ToolSpec

__all__ = ["TOOLS", "ApprovalAction", "Hints", "PlanKind", "ToolGroup", "ToolSpec", "names", "spec_of", "specs"]
