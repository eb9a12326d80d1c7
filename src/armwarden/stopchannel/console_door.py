"""The operator console's E-STOP on the stop channel: who may press it, and from where.

Why a module of its own: the console's button is a browser form posted cross-origin without a
CORS preflight, so its rules (the page's ticket, the console's own origins, loopback without
sign-in) differ from the bearer-token ``POST /estop`` and are tested without a socket.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from armwarden.safety.estop import flatten_reason
from armwarden.stopchannel.listener import is_loopback
from armwarden.stopchannel.wire import HttpRefusal

__all__ = ["CONSOLE_ESTOP_REASON", "CONSOLE_UNSIGNED_PRINCIPAL", "ConsoleDoor", "authorise_console_estop"]

#: the principal audited for a console E-STOP without a ticket (loopback, not signed in)
CONSOLE_UNSIGNED_PRINCIPAL = "console (not signed in, loopback)"
CONSOLE_ESTOP_REASON = "operator console E-STOP"


@dataclass(frozen=True)
class ConsoleDoor:
    """How the channel takes the operator console's E-STOP (``POST /console-estop``).

    `check_ticket` maps a console page's ticket to the signed-in token's name (None: unknown,
    expired or signed out); it runs on the channel's thread, so it must be thread-safe and must
    not wait for the event loop. `allowed_origins`: the console's own origins; a request with
    any other Origin header (``null`` included) is refused, so no other web site can stop the
    robot through a visitor's browser. `back_url`: the link on the answer page.
    """

    check_ticket: Callable[[str], str | None]
    latch_and_stop: Callable[[str, str], int]
    allowed_origins: frozenset[str]
    allow_loopback_without_ticket: bool = True
    back_url: str | None = None


def authorise_console_estop(door: ConsoleDoor, ticket: str | None, peer_host: str) -> str:
    """Who pressed the console's E-STOP: the ticket's session, or, without a valid ticket, a
    loopback peer when the console allows that. The ticket of a page whose session has ended
    (signed out, expired, pushed out by its token's newer sign-ins) still names its token while
    the token is valid (`SessionStore.principal_for_ticket`); a ticket that names nobody (unknown,
    or its token revoked) counts as none: the page that carries it must stop the robot wherever
    a page without one would. `HttpRefusal` 401 otherwise (the stop is
    not issued)."""
    principal = None if ticket is None else door.check_ticket(ticket)
    if principal is not None:
        return flatten_reason(principal, 64) or "unknown"
    why = "no ticket" if ticket is None else "its ticket is unknown or its token revoked: sign in again"
    if not door.allow_loopback_without_ticket:
        raise HttpRefusal(401, f"sign in to the console first ({why})")
    if not is_loopback(peer_host):
        raise HttpRefusal(401, f"without sign-in the console E-STOP works only from this machine ({why})")
    return CONSOLE_UNSIGNED_PRINCIPAL
