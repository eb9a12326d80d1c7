"""The start-up lines of `armwarden serve` that name every URL it serves and what each one takes.

Found in a first hour (issue 31, item 5): HTTP mode never printed its ``/mcp`` and ``/console``
URLs; the one URL it logged was the console's own stop channel, as a WARNING that looked like the
thing to connect to, and which refused every bearer token. These lines go to the log at INFO once
the server listens, with the ports it really bound (port 0 included), and say of the stop
channel what it is for, so that nobody takes it for the MCP endpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Endpoints", "link_host", "startup_lines"]


_WILDCARDS = frozenset({"0.0.0.0", "::", "[::]", ""})


def link_host(host: str) -> str:
    """The host name a link to this daemon uses: a wildcard bind is reached on loopback here."""
    if host in _WILDCARDS:
        return "127.0.0.1"
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


@dataclass(frozen=True)
class Endpoints:
    """What one daemon serves, after binding (every port is the real one)."""

    #: the --auth-tokens file, or None (then nothing takes a token, and only loopback is bound)
    tokens: str | None
    #: host and port of the HTTP transport (``/mcp``), None on stdio
    mcp: tuple[str, int] | None = None
    #: host and port the console (and ``/metrics`` beside it) is served on, None without a console
    console: tuple[str, int] | None = None
    #: host and port of the stop channel, None without one
    channel: tuple[str, int] | None = None
    #: whether the channel takes ``POST /estop`` with a bearer token (--estop-port); if not, it
    #: serves only the console's E-STOP
    channel_takes_tokens: bool = False
    #: whether the console's E-STOP button posts to the channel (else to the console's own route)
    console_posts_to_channel: bool = False


def _base(address: tuple[str, int]) -> str:
    return f"http://{link_host(address[0])}:{address[1]}"


def _where(address: tuple[str, int], path: str, *notes: str) -> str:
    """The URL of `path` at `address`, then its notes in parentheses (a wildcard bind named first)."""
    if address[0] in _WILDCARDS:
        notes = (f"bound to {address[0] or '*'}: every address of this machine", *notes)
    return f"{_base(address)}{path} ({'; '.join(notes)})"


def startup_lines(served: Endpoints) -> list[str]:
    """One line per URL `served` names: what it is, the URL, then what it takes."""
    lines: list[str] = []
    tokens = served.tokens
    if served.mcp is not None:
        needs = (f"every request needs 'Authorization: Bearer <token>' with a token of {tokens}; give an MCP "
                 "client an agent token" if tokens is not None
                 else "no bearer token needed: no --auth-tokens, loopback only")
        lines.append(f"MCP endpoint (streamable HTTP): {_where(served.mcp, '/mcp', needs)}")
    if served.console is not None:
        sign_in = (f"sign in with an operator or observer token of {tokens}" if tokens is not None
                   else "no --auth-tokens: nobody can sign in")
        scrape = "GET with a bearer token of any role" if tokens is not None else "open: no --auth-tokens"
        lines.append(f"operator console: {_where(served.console, '/console/', sign_in)}")
        lines.append(f"Prometheus metrics: {_where(served.console, '/metrics', scrape)}")
    if served.channel is not None:
        base = _base(served.channel)
        if served.channel_takes_tokens:
            notes = [f"a bearer token of any role of {tokens}: armwarden estop --url {base} --token-file FILE",
                     "its own thread and port, not an MCP endpoint"]
            if served.console_posts_to_channel:
                notes.append(f"the console's E-STOP button posts to {base}/console-estop")
            lines.append(f"stop channel: POST {_where(served.channel, '/estop', *notes)}")
        elif served.console_posts_to_channel:
            lines.append("stop channel for the console's E-STOP button only: POST " + _where(
                served.channel, "/console-estop", "takes the console pages' tickets and no bearer token",
                "its own thread and port, not an MCP endpoint",
                "for POST /estop with a token (armwarden estop --url), serve with --estop-port"))
    return lines
