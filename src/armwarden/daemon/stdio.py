"""Serving MCP on stdin and stdout until the client leaves."""

from __future__ import annotations

import logging

from armwarden.daemon.refusals import refusal_recorder, refused_estop_latch
from armwarden.daemon.startup import Assembly
from armwarden.stopchannel.external import ExternalStops

logger = logging.getLogger("armwarden")

async def serve_stdio_client(assembly: Assembly, external: ExternalStops, claimed: tuple[int, int] | None) -> str:
    """Serve until the client leaves, on the pipes `serve_command` claimed (None: none claimed);
    returns how it left, for the shutdown record."""
    from armwarden.transport.stdio import OutputClosed, serve_stdio

    try:
        await serve_stdio(assembly.server.mcp, on_refused=refusal_recorder(assembly),
                          on_stop_request=external.stop_on_receipt, on_input_end=external.latch_as_the_client_leaves,
                          on_estop_refused=refused_estop_latch(assembly, external), claimed=claimed)
    except OutputClosed:
        logger.warning("the client closed the daemon's stdout: its open calls are cancelled and the daemon stops")
        return "the client closed stdout"
    return "end of stdin"
