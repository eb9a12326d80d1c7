"""Registers the tools of one policy on one MCPServer: each tool's record (`armwarden.tools`)
joined with its face (`server.faces`), through the SDK's public `Tool.from_function`.

A record decides whether the tool exists here (its group enabled by the policy — the safety
group always is —, its backend capability present) and how it is annotated; the face gives its
schema and description. Every call is admitted by the Guard's rate limiter before its body runs,
and a refusal becomes the tool's `isError` answer that says why and what a human must do.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from mcp.server.mcpserver.tools import Tool
from mcp_types import CallToolResult, ToolAnnotations

from armwarden.core.errors import ConfigurationError, RefusalCode, SafetyRefusal
from armwarden.guard import Guard
from armwarden.policy import Policy
from armwarden.server.calls import mark_body_ran, refused
from armwarden.server.faces import GROUP_FACES, Face, FaceContext, Faces
from armwarden.tools import TOOLS, Hints, ToolSpec

logger = logging.getLogger(__name__)

#: what a group needs from the policy besides being enabled: the cameras it allowlists, its gripper
_POLICY_PROVIDES: dict[str, Callable[[Policy], bool]] = {
    "perception": lambda policy: bool(policy.perception.cameras),
    "gripper": lambda policy: policy.gripper is not None,
}


def annotations_of(hints: Hints) -> ToolAnnotations:
    return ToolAnnotations(read_only_hint=hints.read_only, destructive_hint=hints.destructive,
                           idempotent_hint=hints.idempotent, open_world_hint=hints.open_world)


class ToolBuilder:
    """Builds the tools of one policy and Guard, in the order of the tool reference."""

    def __init__(self, guard: Guard) -> None:
        self.guard = guard
        self.policy = guard.policy
        self.capabilities = guard.capabilities
        #: the names of the tools built, in order
        self.registered: list[str] = []

    def available(self, spec: ToolSpec) -> bool:
        """Does the tool exist on this server (its group enabled, its capability and policy section present)?"""
        enabled = spec.group == "safety" or spec.group in self.policy.tools.enabled
        capable = spec.capability is None or bool(getattr(self.capabilities, spec.capability))
        provided = _POLICY_PROVIDES.get(spec.group, lambda _: True)(self.policy)
        return enabled and capable and provided

    def build(self) -> list[Tool]:
        """The SDK tools for every available record, each joined with its face."""
        context = FaceContext(self.guard, self.policy, self.capabilities, self.registered, self.answer)
        built: list[Tool] = []
        faces: dict[str, Faces] = {}  # each group's, built once it has an available tool
        for spec in TOOLS:
            if not self.available(spec):
                continue
            if spec.group not in faces:
                faces[spec.group] = GROUP_FACES[spec.group](context)
            face = faces[spec.group].get(spec.name)
            if face is None:
                raise ConfigurationError(f"the tool {spec.name} has a record but no face in its group ({spec.group})")
            built.append(self._tool(spec, face))
        return built

    def _tool(self, spec: ToolSpec, face: Face) -> Tool:
        function = face.function if face.answers_itself else self._admitting(spec.name, face.function)
        tool = Tool.from_function(function, name=spec.name, description=face.description,
                                  annotations=annotations_of(spec.hints))
        schema = tool.fn_metadata.output_schema
        if schema is None or schema.get("title") != spec.result.__name__:
            raise ConfigurationError(f"the face of {spec.name} returns {None if schema is None else schema.get('title')}, "
                                     f"its record says {spec.result.__name__}")
        # Publish self-contained output schemas: every client validates each result against it, and
        # `$ref` resolution made that validation cost more than the call itself.
        inlined = inline_refs(schema)
        schema.clear()
        schema.update(inlined)
        self.registered.append(spec.name)
        return tool

    def _admitting(self, tool: str, function: Callable[..., Awaitable[CallToolResult]]) -> Callable[..., Awaitable[CallToolResult]]:
        """`function` with each call answered through `answer` (the signature, the tool's schema, kept)."""

        @functools.wraps(function)
        async def call(*args: Any, **kwargs: Any) -> CallToolResult:
            return await self.answer(tool, lambda: function(*args, **kwargs))

        return call

    async def answer(self, tool: str, body: Callable[[], Awaitable[CallToolResult]]) -> CallToolResult:
        """The one error boundary of every tool: the call is admitted by the rate limiter
        (`Guard.admit`, which refuses) and its body run; refusals become `isError` results that say
        why; an unexpected failure is logged with its traceback and answered without internals."""
        mark_body_ran()
        try:
            self.guard.admit(tool)
            return await body()
        except SafetyRefusal as exc:
            logger.info("%s refused [%s]: %s", tool, exc.code, exc)
            return refused(exc)
        except Exception:
            logger.exception("%s failed unexpectedly", tool)
            return refused(SafetyRefusal(
                RefusalCode.INTERNAL_ERROR,
                f"{tool} failed inside the server (see its log); nothing further was done. If the arm "
                "moved, call stop_motion; a human should check the robot.",
            ))


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """A copy of a JSON schema with every local `#/$defs/...` reference replaced by its definition."""
    definitions = schema.get("$defs", {})

    def resolve(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                merged = {**resolve(definitions[ref[len("#/$defs/"):]]), **{k: resolve(v) for k, v in node.items() if k != "$ref"}}
                return merged
            return {k: resolve(v) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [resolve(item) for item in node]
        return node

    return resolve(schema)


__all__ = ["ToolBuilder", "annotations_of", "inline_refs"]
