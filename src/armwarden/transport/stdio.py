"""MCP over stdio: the SDK's stdio transport, with ArmWarden's gate between it and the server.

`serve_stdio` runs the server's low-level session over stdin/stdout (the claimed pipes of
`pipes.py` when there are any) through `stdio_gate.gate_streams`, which answers what the SDK
would drop (unreadable lines, calls without a usable id, reused open ids), latches refused
`estop` calls and reports refusals for the audit log. A client that closes the daemon's stdout
ends the session with `OutputClosed`, not with the SDK's nested exception groups.

Lean on purpose: serving on stdio imports nothing of the HTTP transport.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from contextlib import nullcontext
from typing import Any, cast

import anyio
from mcp.server.mcpserver import MCPServer
from mcp.server.stdio import stdio_server

from armwarden.transport.jsonrpc import LatchOnRefusal, RefusedCallback, StopOnReceipt
from armwarden.transport.pipes import PipeLineReader, PipeWriter, claimed_pipes
from armwarden.transport.stdio_gate import gate_streams

__all__ = ["UNCLAIMED", "OutputClosed", "Unclaimed", "serve_stdio"]


class Unclaimed:
    """`serve_stdio`'s default: no caller claimed the pipes, so the session claims them itself."""


UNCLAIMED = Unclaimed()


class OutputClosed(ConnectionError):
    """The client closed its end of the daemon's stdout during the session: no answer can reach it
    any more, so the session ends, as it does when the input ends (the calls still open are
    cancelled, which stops a motion)."""


def _only_a_closed_output(exc: BaseException) -> bool:
    """Whether `exc`, as the SDK's stdio task groups raise it (nested exception groups), holds
    nothing but a stdout whose reader is gone: EPIPE on a pipe, a reset or EPIPE on a socket."""
    if isinstance(exc, (BrokenPipeError, ConnectionResetError)):
        return True
    inner = getattr(exc, "exceptions", None)  # an exception group (anyio's backport on 3.10)
    return bool(inner) and all(_only_a_closed_output(e) for e in inner)


async def serve_stdio(server: MCPServer, *, on_refused: RefusedCallback | None = None,
                      on_stop_request: StopOnReceipt | None = None,
                      on_input_end: Callable[[], None] | None = None,
                      on_estop_refused: LatchOnRefusal | None = None,
                      claimed: tuple[int, int] | Unclaimed | None = UNCLAIMED) -> None:
    """Serve `server` on stdin/stdout until stdin ends (what `MCPServer.run_stdio_async` does,
    with the gate in between). Pending duplicate reports finish before this returns. Raises
    `OutputClosed` when the client closed the daemon's stdout (the SDK's transport would end the
    session with a traceback of nested exception groups).

    `claimed`: the wires of a `claimed_pipes` the caller holds (the daemon claims them before it
    opens its backend, whose native libraries may write to fd 1), None when it found none to claim;
    by default they are claimed here, for the session only."""
    # MCPServer runs its low-level server over the SDK's stdio streams and offers no public hook
    # between the two; the low-level server is the documented way to serve custom streams.
    lowlevel = server._lowlevel_server
    with claimed_pipes() if isinstance(claimed, Unclaimed) else nullcontext(claimed) as wires:
        stdin = None if wires is None else PipeLineReader(wires[0])
        stdout = None if wires is None else PipeWriter(wires[1])
        try:
            async with stdio_server(cast(Any, stdin), cast(Any, stdout)) as (read_stream, write_stream), \
                    anyio.create_task_group() as reports:
                def spawn(fn: Callable[..., Coroutine[Any, Any, None]], *args: Any) -> None:
                    reports.start_soon(fn, *args)

                gated_read, gated_write = gate_streams(read_stream, write_stream, spawn, on_refused, on_stop_request,
                                                       on_input_end, on_estop_refused)
                await lowlevel.run(gated_read, gated_write, lowlevel.create_initialization_options())
        except BaseException as exc:
            if _only_a_closed_output(exc):
                raise OutputClosed("the client closed the daemon's stdout") from None
            raise
        finally:
            for end in (stdin, stdout):
                if end is not None:
                    end.close()
