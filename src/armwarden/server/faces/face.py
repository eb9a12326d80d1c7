"""What a tool's MCP face is: its description and the function whose signature is its input and
output schema, and what a face may use to build itself (`FaceContext`).

The record of the tool (`armwarden.tools`) says what the tool is; the face says how it looks to
a client for this policy (bounds in its schema, frames and cameras in its description) and hands
the call to the Guard. The builder (`server.registration`) joins the two.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from mcp_types import CallToolResult

from armwarden.backends.parts import Capabilities
from armwarden.guard import Guard
from armwarden.policy import Policy

#: a tool body: returns its result (see `server.calls.ok`), raises `SafetyRefusal` to refuse
ToolBody = Callable[..., Awaitable[CallToolResult]]
#: a face's function, before it is registered
FaceFunction = Callable[..., Awaitable[Any]]
#: runs a call's body inside the error boundary and the rate limiter (see `FaceContext.answer`)
Answer = Callable[[str, Callable[[], Awaitable[CallToolResult]]], Awaitable[CallToolResult]]


@dataclass(frozen=True)
class Face:
    """One tool as a client sees it."""

    description: str
    #: named as the tool; its parameters are the input schema, its return annotation the output's
    function: FaceFunction
    #: the function admits and answers its call itself (`FaceContext.answer`): it may first answer
    #: with a question round (InputRequiredResult), which is not admitted
    answers_itself: bool = False


class Faces(dict[str, Face]):
    """The faces of one tool group, by tool name."""

    def add(self, description: str, *, answers_itself: bool = False) -> Callable[[FaceFunction], FaceFunction]:
        """Decorator: the function is the face of the tool of the same name."""

        def register(function: FaceFunction) -> FaceFunction:
            self[function.__name__] = Face(description, function, answers_itself)
            return function

        return register


@dataclass(frozen=True)
class FaceContext:
    """What a face is built from: the Guard it calls, the policy and capabilities it describes."""

    guard: Guard
    policy: Policy
    capabilities: Capabilities
    #: the tools registered on this server, in order (filled while the builder runs)
    registered: list[str]
    #: admit a call (rate limiter) and answer it (refusals become `isError` results)
    answer: Answer
