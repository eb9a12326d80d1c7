"""Console sign-in: a bearer token from the HTTP token file buys a browser session.

Why sessions and not the token itself: the token must not live in a page or in JavaScript. The
operator pastes it once; the server answers with an opaque session id in a cookie the page's
scripts cannot read (HttpOnly) and that no other site's request carries (SameSite=Strict). Each
session has its own CSRF token, which every POST must echo (form field or header). Sessions live
in memory only: a daemon restart signs everyone out. The token is re-checked against the token
file on each request, so revoking it ends its sessions at once.

The E-STOP button posts to the independent stop channel, another origin that cannot see the
cookie. So each session also has an E-STOP ticket the page embeds: an HMAC of the session id
under a secret drawn per store (per daemon), unguessable and revealing nothing of the session
id. The stop channel's thread checks it (`principal_for_ticket`) without the event loop, hence
the lock around the session table.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from armwarden.transport.tokens import Principal, TokenStore

__all__ = ["COOKIE", "LOGIN_COOKIE", "Session", "SessionStore", "same_secret"]

COOKIE = "armwarden_console"
#: a random value set with the sign-in form and echoed by it (CSRF on the one POST without a session)
LOGIN_COOKIE = "armwarden_console_login"
#: a session ends this long after sign-in [s]
SESSION_TTL_S = 8 * 3600.0
MAX_SESSIONS = 64


def same_secret(presented: object, expected: str) -> bool:
    """Constant-time comparison; anything but a non-empty string is a mismatch."""
    return isinstance(presented, str) and bool(presented) and hmac.compare_digest(presented.encode(), expected.encode())


@dataclass(frozen=True)
class Session:
    """A signed-in browser: who (the token's name and role) and its CSRF token."""

    session_id: str
    name: str
    role: str
    csrf: str
    expires_mono: float
    token_fingerprint: str  # for the audit log; the token itself stays in this process's memory only
    estop_ticket: str = ""  # the page's authority for the stop channel's console E-STOP

    @property
    def can_approve(self) -> bool:
        return self.role == "operator"


class SessionStore:
    """Sessions of one console, keyed by an unguessable id."""

    def __init__(self, tokens: TokenStore | None, clock: Callable[[], float] = time.monotonic,
                 ttl_s: float = SESSION_TTL_S) -> None:
        self._tokens = tokens
        self._clock = clock
        self._ttl_s = ttl_s
        self._sessions: OrderedDict[str, tuple[Session, str]] = OrderedDict()
        self._tickets: dict[str, str] = {}  # E-STOP ticket -> session id
        self._secret = secrets.token_bytes(32)
        self._lock = threading.Lock()  # the stop channel's thread reads the table too

    @property
    def enabled(self) -> bool:
        """Sign-in needs a token file; without one nobody can sign in (the E-STOP still works)."""
        return self._tokens is not None

    def sign_in(self, token: object) -> Session | None:
        """A new session for a valid token; None for anything else."""
        if self._tokens is None or not isinstance(token, str) or not token.strip():
            return None
        presented = token.strip()
        principal = self._tokens.authenticate(presented)
        if principal is None:
            return None
        session_id = secrets.token_urlsafe(32)
        session = Session(session_id, principal.name, principal.role, secrets.token_urlsafe(32),
                          self._clock() + self._ttl_s, _fingerprint(presented), self._ticket_for(session_id))
        with self._lock:
            self._sessions[session.session_id] = (session, presented)
            self._tickets[session.estop_ticket] = session.session_id
            while len(self._sessions) > MAX_SESSIONS:
                oldest, _ = self._sessions.popitem(last=False)  # the oldest sign-in goes first
                self._tickets = {t: s for t, s in self._tickets.items() if s != oldest}
        return session

    def lookup(self, session_id: object) -> Session | None:
        """The live session for a cookie value: unexpired, and its token still valid with the same role."""
        if not isinstance(session_id, str) or self._tokens is None:
            return None
        with self._lock:
            entry = self._sessions.get(session_id)
        if entry is None:
            return None
        session, presented = entry
        principal: Principal | None = self._tokens.authenticate(presented)
        if self._clock() >= session.expires_mono or principal is None or principal.role != session.role:
            self._forget(session_id)
            return None
        return session

    def principal_for_ticket(self, ticket: object) -> str | None:
        """The token name of the live session an E-STOP `ticket` belongs to; None for anything else.
        Thread-safe: the stop channel calls it on its own thread."""
        if not isinstance(ticket, str) or not ticket:
            return None
        with self._lock:
            session_id = self._tickets.get(ticket)
        if session_id is None:
            return None
        session = self.lookup(session_id)
        return None if session is None or not same_secret(ticket, session.estop_ticket) else session.name

    def sign_out(self, session_id: object) -> Session | None:
        if not isinstance(session_id, str):
            return None
        return self._forget(session_id)

    def _forget(self, session_id: str) -> Session | None:
        with self._lock:
            entry = self._sessions.pop(session_id, None)
            if entry is not None:
                self._tickets.pop(entry[0].estop_ticket, None)
        return None if entry is None else entry[0]

    def _ticket_for(self, session_id: str) -> str:
        mac = hmac.new(self._secret, b"console-estop\0" + session_id.encode(), hashlib.sha256).digest()
        return base64.urlsafe_b64encode(mac).decode().rstrip("=")


def _fingerprint(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()[:16]
