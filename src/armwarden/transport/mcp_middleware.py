"""The MCP server middleware the HTTP app installs, so the transport knows what the tools saw.

`mark_dispatched` (outermost) notes, for the POST being served (`noting_dispatch`), that its
`tools/call` reached the server's middleware chain: an error answer to such a call was recorded by
the tool layer and `AbandonedMotionStop` does not record it again as a refusal.
`LatchEstopsNotRun` (right inside it) latches the e-stop for an `estop` call the SDK refused or
cancelled after the transport passed it on.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextvars import ContextVar
from typing import Any

from mcp.server.context import CallNext, ServerRequestContext

from armwarden.transport.access import current_principal
from armwarden.transport.jsonrpc import LatchOnRefusal, refused_stops, stop_call

__all__ = ["LatchEstopsNotRun", "mark_dispatched", "noting_dispatch"]

#: per POST to the MCP endpoint: `mark_dispatched` notes there that its `tools/call` reached the
#: server's middleware chain (the tool layer's audit records such a call itself)
_DISPATCHED: ContextVar[list[str] | None] = ContextVar("armwarden_dispatched", default=None)


async def mark_dispatched(ctx: ServerRequestContext[Any, Any], call_next: CallNext) -> Any:
    """MCP server middleware, installed outermost by the HTTP app: notes that the `tools/call` of
    the request being served reached the tools' side, so an error answer to it is not recorded
    again as a refusal (`AbandonedMotionStop`)."""
    if ctx.method == "tools/call" and (seen := _DISPATCHED.get()) is not None:
        seen.append(ctx.method)
    return await call_next(ctx)


class LatchEstopsNotRun:
    """MCP server middleware, installed by the HTTP app: an `estop` call that reached the server
    but ended without an answer of its tool — refused by the SDK after the transport passed it on
    (a forged or expired 2026-07-28 request state, params its validation rejects) or cancelled
    (its 2026-07-28 client hung up) — latches the e-stop all the same, before the error goes out
    (a readable estop request shows the intent; `refused_stops`)."""

    def __init__(self, latch: LatchOnRefusal) -> None:
        self.latch = latch

    async def __call__(self, ctx: ServerRequestContext[Any, Any], call_next: CallNext) -> Any:
        if stop_call(ctx.method, ctx.params) != "estop":
            return await call_next(ctx)
        try:
            return await call_next(ctx)
        except BaseException as exc:
            principal = current_principal()
            why = f"the estop call ended without its tool's answer ({type(exc).__name__}: {str(exc)[:200]})"
            refused_stops([("estop", ctx.params)], self.latch, None if principal is None else principal.name, why)
            raise


@contextlib.contextmanager
def noting_dispatch(dispatched: list[str]) -> Iterator[None]:
    """While serving one POST: `mark_dispatched` appends to `dispatched` when its call reaches the tools."""
    token = _DISPATCHED.set(dispatched)
    try:
        yield
    finally:
        _DISPATCHED.reset(token)
