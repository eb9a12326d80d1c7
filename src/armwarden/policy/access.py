"""The `tools`, `rate_limits` and `approval` sections: which tools exist, how often, and who approves."""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, Field, WrapSerializer

from armwarden.policy.constants import ALL_TOOLS, APPROVAL_ACTIONS, RATE_LIMIT_EXEMPT_TOOLS, TOOL_GROUPS
from armwarden.policy.fields import MODEL_CONFIG, FrozenMap, Rate, StrictBool, freeze_map, serialize_map
from armwarden.tools import ApprovalAction, ToolGroup


def _normalise_groups(groups: tuple[str, ...]) -> tuple[str, ...]:
    """`safety` (stop, e-stop, ...) can never be switched off; order is canonical, repeats dropped."""
    wanted = set(groups) | {"safety"}
    return tuple(group for group in TOOL_GROUPS if group in wanted)


class ToolsConfig(BaseModel):
    """Which tool groups are registered. A disabled tool does not appear in `tools/list` at all."""

    model_config = MODEL_CONFIG

    enabled: Annotated[tuple[ToolGroup, ...], AfterValidator(_normalise_groups)] = Field(
        default=("introspect", "safety"),
        description=(
            "Enabled tool groups (no unit), a subset of introspect, perception, motion, gripper, control, "
            "safety; `safety` is always added."
        ),
    )

    @property
    def tools(self) -> tuple[str, ...]:
        """Every tool name of the enabled groups."""
        return tuple(tool for group in self.enabled for tool in TOOL_GROUPS[group])


def _check_rate_limited_tool(name: str) -> str:
    """Per-tool overrides must name a real, throttled tool; anything else would be silently ignored."""
    if name in RATE_LIMIT_EXEMPT_TOOLS:
        raise ValueError(
            f"{name!r} is never rate limited (exempt: {', '.join(RATE_LIMIT_EXEMPT_TOOLS)}); remove this entry"
        )
    if name not in ALL_TOOLS:
        hint = difflib.get_close_matches(name, ALL_TOOLS, n=1)
        did_you_mean = f"did you mean {hint[0]!r}? " if hint else ""
        raise ValueError(f"unknown tool name {name!r}; {did_you_mean}valid tools: {', '.join(ALL_TOOLS)}")
    return name


RateLimitedTool = Annotated[str, Field(strict=True), AfterValidator(_check_rate_limited_tool)]


class RateLimitsConfig(BaseModel):
    """Token buckets with continuous refill. stop_motion, estop and get_safety_status are exempt."""

    model_config = MODEL_CONFIG

    global_per_minute: Rate = Field(default=120, description="Calls per minute [1/min] across all tools.")
    default_per_minute: Rate = Field(default=60, description="Calls per minute [1/min] per tool without an override.")
    per_tool: Annotated[
        Mapping[RateLimitedTool, Rate], AfterValidator(freeze_map), WrapSerializer(serialize_map)
    ] = Field(default_factory=FrozenMap, description="Per-tool overrides: tool name → calls per minute [1/min].")

    def limit_for(self, tool: str) -> int:
        """Calls per minute allowed for `tool` (its override, else the default)."""
        return self.per_tool.get(tool, self.default_per_minute)


def _normalise_require_for(actions: tuple[str, ...]) -> tuple[str, ...]:
    """Releasing an e-stop always needs a human (docs/architecture.md, "Where each limit is enforced");
    order is canonical, repeats dropped."""
    wanted = set(actions) | {"reset_estop"}
    return tuple(action for action in APPROVAL_ACTIONS if action in wanted)


class ApprovalConfig(BaseModel):
    """When a human must approve, through the client's elicitation UI or the operator console."""

    model_config = MODEL_CONFIG

    mode: Literal["always", "outside_envelope", "never"] = Field(
        default="outside_envelope",
        description="always: every approvable action; outside_envelope: only with soft violations; never (no unit).",
    )
    on_client_without_elicitation: Literal["deny", "allow"] = Field(
        default="deny",
        description="What to do when approval is needed but the client cannot ask (no unit); "
        "`reset_estop` always needs a human.",
    )
    channel: Literal["form", "url", "both"] = Field(
        default="form",
        description="Where the human answers a motion's approval (no unit): form, the MCP client's elicitation "
        "form; url, the operator console page of that request (MCP URL-mode elicitation points there), never the "
        "requesting client's own form (a client that cannot open the link, reset_estop and the control actions are "
        "refused there; reset_estop is released in the console); both, whichever answers first (the other is "
        "withdrawn).",
    )
    require_for: Annotated[tuple[ApprovalAction, ...], AfterValidator(_normalise_require_for)] = Field(
        default=APPROVAL_ACTIONS,
        description="Actions (no unit) that go through approval; `reset_estop` is always included.",
    )
    allow_self_approval: StrictBool = Field(
        default=False,
        description="Whether the token that requested a motion may approve it itself in the operator console "
        "(boolean), and, under channel url, whether the requesting client's own form may stand in. Off: another "
        "operator must approve in the console (the requester may still decline). On, for single-user desks: the "
        "console page or the form's question, and the audit record, say the approver is the requester.",
    )

