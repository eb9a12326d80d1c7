"""Public constants of the policy format: tool groups, approvable actions, size limits.

The tool names are a public contract (clients and prompts rely on them); the order of the
groups is the order the tool reference lists them in.
"""

from __future__ import annotations

from typing import Literal

#: Tool group → tool names, in the order of the tool reference (docs/tools.md). The names are a public contract.
TOOL_GROUPS: dict[str, tuple[str, ...]] = {
    "introspect": (
        "get_robot_state",
        "get_safety_envelope",
        "lookup_transform",
        "list_controllers",
        "list_ros_graph",
        "get_audit_tail",
    ),
    "perception": ("camera_snapshot",),
    "motion": ("plan_to_joints", "plan_to_pose", "plan_cartesian_path", "execute_plan", "get_motion_status"),
    "gripper": ("gripper_move", "gripper_grasp", "gripper_home"),
    "control": ("switch_controllers", "set_collision_thresholds"),
    "safety": ("stop_motion", "estop", "reset_estop", "error_recovery", "get_safety_status"),
}
#: Every tool name, group by group.
ALL_TOOLS: tuple[str, ...] = tuple(tool for tools in TOOL_GROUPS.values() for tool in tools)
#: Tools the rate limiter never throttles: stopping must always work (docs/architecture.md, "Concurrency model").
RATE_LIMIT_EXEMPT_TOOLS: tuple[str, ...] = ("stop_motion", "estop", "get_safety_status")
#: Actions that can be put behind human approval; `reset_estop` is always among them.
APPROVAL_ACTIONS: tuple[ApprovalAction, ...] = (
    "execute",
    "switch_controllers",
    "reset_estop",
    "error_recovery",
    "set_collision_thresholds",
)
#: Policy files larger than this are refused before parsing.
MAX_POLICY_BYTES = 1024 * 1024
#: The path reported for problems with the document as a whole (unreadable, not YAML, not a mapping).
DOCUMENT_PATH = "<document>"

BUILTIN_PREFIX = "builtin:"
DEFAULT_SCALING = 0.1

ToolGroup = Literal["introspect", "perception", "motion", "gripper", "control", "safety"]
ApprovalAction = Literal["execute", "switch_controllers", "reset_estop", "error_recovery", "set_collision_thresholds"]
