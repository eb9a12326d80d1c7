"""Public constants of the policy format: tool groups, approvable actions, size limits.

The tool names are a public contract (clients and prompts rely on them); they, their groups and
the approvable actions come from the tool catalogue (`armwarden.tools`), in its order.
"""

from __future__ import annotations

from typing import get_args

from armwarden.tools import TOOLS, ApprovalAction, ToolGroup

#: Tool group → tool names, in the order of the tool reference (docs/tools.md). The names are a public contract.
TOOL_GROUPS: dict[str, tuple[str, ...]] = {
    group: tuple(spec.name for spec in TOOLS if spec.group == group) for group in get_args(ToolGroup)
}
#: Every tool name, group by group.
ALL_TOOLS: tuple[str, ...] = tuple(tool for tools in TOOL_GROUPS.values() for tool in tools)
#: Tools the rate limiter never throttles: stopping must always work (docs/architecture.md, "Concurrency model").
RATE_LIMIT_EXEMPT_TOOLS: tuple[str, ...] = tuple(spec.name for spec in TOOLS if spec.rate_exempt)
#: Actions that can be put behind human approval; `reset_estop` is always among them.
APPROVAL_ACTIONS: tuple[ApprovalAction, ...] = get_args(ApprovalAction)
#: Policy files larger than this are refused before parsing.
MAX_POLICY_BYTES = 1024 * 1024
#: The path reported for problems with the document as a whole (unreadable, not YAML, not a mapping).
DOCUMENT_PATH = "<document>"

DEFAULT_SCALING = 0.1
