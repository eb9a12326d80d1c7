"""Console sign-in: a bearer token from the HTTP token file buys a browser session.

Why sessions and not the token itself: the token must not live in a page or in JavaScript. The
operator pastes it once; the server answers with an opaque session id in a cookie the page's
scripts cannot read (HttpOnly) and that no other site's request carries (SameSite=Strict). Each
session has its own CSRF token, which every POST must echo (form field or header). Sessions live
in memory only: a daemon restart signs everyone out. The token is re-checked against the token
file on each request, so revoking it ends its sessions at once.

What a page says after an action (released, refused, approved) is a flash kept here for the
session that acted (`put_flash`, `take_flash`): one-time, and named in the redirect's URL only by
an opaque id that means nothing to another session, so no link can make a page claim a status.

The console is for humans: an `agent` token (an MCP client's) cannot sign in at all. Were the
agent's own token good for a session, the agent could sign in like a script and approve or
release there what it asked for.

Room is shared fairly: at most `MAX_SESSIONS_PER_PRINCIPAL` sessions per token name (a new
sign-in ends that token's own oldest one) and `MAX_SESSIONS` in all, of which observers hold at
most `MAX_OBSERVER_SESSIONS`: the rest is kept for operators, the people who release the e-stop
and approve, so observer tokens cannot lock them out. A sign-in never ends a session of another
token to make room: when the table (or the observers' part of it) is full of other tokens'
sessions, the new sign-in is refused with a message that says so. (Before, any token holder
could sign in 64 times and sign everyone else out.)

The E-STOP button posts to the independent stop channel, another origin that cannot see the
cookie. So each session also has an E-STOP ticket the page embeds: an HMAC of the session id
under a secret drawn per store (per daemon), unguessable and revealing nothing of the session
id. The stop channel's thread checks it (`principal_for_ticket`) without the event loop, hence
the lock around the session table. A ticket outlives its session: a page left open while its
session expired, was pushed out or signed out in another tab still shows an E-STOP, and a stop
is always safe to accept, so the ticket stops for as long as its token is valid (a revoked
token's ticket does not), audited as "NAME (session ended)". The tickets of ended sessions are
kept per token name, at most `MAX_ENDED_TICKETS_PER_PRINCIPAL` each: one token's churn never
forgets another's.
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
from typing import Literal

from armwarden.transport.tokens import Principal, TokenStore

__all__ = ["COOKIE", "LOGIN_COOKIE", "Session", "SessionStore", "SignInRefused", "same_secret"]

COOKIE = "armwarden_console"
#: a random value set with the sign-in form and echoed by it (CSRF on the one POST without a session)
LOGIN_COOKIE = "armwarden_console_login"
#: a session ends this long after sign-in [s]
SESSION_TTL_S = 8 * 3600.0
#: sessions in all; when full of other tokens' sessions, a sign-in is refused (none is ended for it)
MAX_SESSIONS = 64
#: sessions of one token name; its new sign-in ends its own oldest session
MAX_SESSIONS_PER_PRINCIPAL = 8
#: sessions observers hold in all; the other `MAX_SESSIONS - MAX_OBSERVER_SESSIONS` are kept for operators
MAX_OBSERVER_SESSIONS = 32
#: tickets of ended sessions kept per token name, so their pages' E-STOP still stops
MAX_ENDED_TICKETS_PER_PRINCIPAL = 32
#: how the principal of a stop from the page of an ended session is audited
SESSION_ENDED = "session ended"
#: flashes waiting to be shown per session (a redirect not followed leaves one; the oldest goes)
MAX_FLASHES_PER_SESSION = 8
#: a flash: a message code of `pages.MESSAGES` and its e-stop event number, if it has one
Flash = tuple[str, int | None]


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


@dataclass(frozen=True)
class SignInRefused:
    """Why a sign-in got no session: `invalid_token` (unknown, revoked, none given, or sign-in is
    off), `agent_token` (an MCP client's token: the console is for humans) or `full` (the console
    holds `MAX_SESSIONS` sessions of other tokens)."""

    reason: Literal["invalid_token", "agent_token", "full"]
    message: str
    #: the token's name when the token was valid (`agent_token`, `full`); None for an invalid one
    name: str | None = None


@dataclass(frozen=True)
class _Ticket:
    """What an E-STOP ticket stands for: its session and the token that signed in."""

    session_id: str
    name: str
    presented: str  # the token, to re-check it (revoked: the ticket no longer stops)


class SessionStore:
    """Sessions of one console, keyed by an unguessable id."""

    def __init__(self, tokens: TokenStore | None, clock: Callable[[], float] = time.monotonic,
                 ttl_s: float = SESSION_TTL_S, max_sessions: int = MAX_SESSIONS,
                 max_per_principal: int = MAX_SESSIONS_PER_PRINCIPAL,
                 max_observer_sessions: int = MAX_OBSERVER_SESSIONS) -> None:
        if max_sessions < 1 or not 1 <= max_per_principal <= max_sessions:
            raise ValueError(f"session limits must satisfy 1 <= per token ({max_per_principal}) <= all ({max_sessions})")
        if max_observer_sessions < 1:
            raise ValueError(f"observers' sessions ({max_observer_sessions}) must be at least 1")
        self._tokens = tokens
        self._clock = clock
        self._ttl_s = ttl_s
        self._max_sessions = max_sessions
        self._max_per_principal = max_per_principal
        #: observers' part of the table (all of a table no larger than it: nothing kept for operators)
        self._max_observer_sessions = min(max_observer_sessions, max_sessions)
        self._sessions: OrderedDict[str, tuple[Session, str]] = OrderedDict()  # oldest sign-in first
        self._tickets: dict[str, _Ticket] = {}  # E-STOP ticket -> what it stands for (live and ended sessions)
        self._ended: dict[str, OrderedDict[str, None]] = {}  # token name -> tickets of its ended sessions, oldest first
        self._flashes: dict[str, OrderedDict[str, Flash]] = {}  # session id -> its flashes by id, oldest first
        self._secret = secrets.token_bytes(32)
        self._lock = threading.Lock()  # the stop channel's thread reads the table too

    @property
    def enabled(self) -> bool:
        """Sign-in needs a token file; without one nobody can sign in (the E-STOP still works)."""
        return self._tokens is not None

    def sign_in(self, token: object) -> Session | SignInRefused:
        """A new session for a valid token, or why not. At the token's own limit its oldest
        session ends; a table full of other tokens' sessions refuses (never ends one of theirs)."""
        if self._tokens is None or not isinstance(token, str) or not token.strip():
            return SignInRefused("invalid_token", "That token is not valid (unknown or revoked).")
        presented = token.strip()
        principal = self._tokens.authenticate(presented)
        if principal is None:
            return SignInRefused("invalid_token", "That token is not valid (unknown or revoked).")
        if principal.role == "agent":
            return SignInRefused("agent_token", "That is an agent's token (for MCP clients): the console is for humans. "
                                 "Sign in with an operator or observer token.", principal.name)
        self._end_dead_sessions()
        session_id = secrets.token_urlsafe(32)
        session = Session(session_id, principal.name, principal.role, secrets.token_urlsafe(32),
                          self._clock() + self._ttl_s, _fingerprint(presented), self._ticket_for(session_id))
        with self._lock:
            own = [sid for sid, (s, _) in self._sessions.items() if s.name == principal.name]
            if len(own) >= self._max_per_principal:
                self._end_locked(own[0])  # this token's own oldest sign-in makes room
            elif len(self._sessions) >= self._max_sessions:
                return SignInRefused("full", (
                    f"The console already has {len(self._sessions)} sessions open (at most {self._max_per_principal} "
                    "per token); no one else is signed out to make room. Ask someone to sign out, or wait until a "
                    "session ends."), principal.name)
            elif principal.role != "operator" and self._observers_locked() >= self._max_observer_sessions:
                return SignInRefused("full", (
                    f"Observers already hold {self._max_observer_sessions} console sessions, all they may (the rest "
                    "is kept for operators); no one else is signed out to make room. Ask an observer to sign out, or "
                    "wait until a session ends."), principal.name)
            self._sessions[session.session_id] = (session, presented)
            self._tickets[session.estop_ticket] = _Ticket(session.session_id, principal.name, presented)
        return session

    def _observers_locked(self) -> int:
        """Sessions of tokens that are not operators (call with the lock held)."""
        return sum(1 for session, _ in self._sessions.values() if not session.can_approve)

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
            self._end(session_id)
            return None
        return session

    def principal_for_ticket(self, ticket: object) -> str | None:
        """Who pressed the E-STOP of a page carrying `ticket`: the token's name while its session
        lives, "NAME (session ended)" once it has ended (expired, pushed out, signed out), None for
        anything else (unknown, forged, or its token revoked). A token file that became unusable
        does not refuse a stop: its last usable version decides. Thread-safe: the stop channel
        calls it on its own thread."""
        if not isinstance(ticket, str) or not ticket or self._tokens is None:
            return None
        with self._lock:
            entry = self._tickets.get(ticket)
        if entry is None or not same_secret(ticket, self._ticket_for(entry.session_id)):
            return None
        principal = self._tokens.authenticate(entry.presented, last_good_while_unusable=True)
        if principal is None or principal.name != entry.name:
            return None
        with self._lock:
            live = self._sessions.get(entry.session_id)
        if live is not None and self._clock() < live[0].expires_mono:
            return entry.name
        return f"{entry.name} ({SESSION_ENDED})"

    def put_flash(self, session: Session, code: str, event: int | None = None) -> str:
        """Keep what the next page of `session` says (`code`, with `event` where its text has one);
        the opaque id its redirect carries."""
        flash_id = secrets.token_urlsafe(16)
        with self._lock:
            if session.session_id not in self._sessions:
                return flash_id  # ended meanwhile: nothing to show it to
            flashes = self._flashes.setdefault(session.session_id, OrderedDict())
            flashes[flash_id] = (code, event)
            while len(flashes) > MAX_FLASHES_PER_SESSION:
                flashes.popitem(last=False)
        return flash_id

    def take_flash(self, session: Session, flash_id: object) -> Flash | None:
        """The flash `flash_id` of `session`, once; None for anything else (another session's,
        shown already, unknown)."""
        if not isinstance(flash_id, str):
            return None
        with self._lock:
            return self._flashes.get(session.session_id, OrderedDict()).pop(flash_id, None)

    def sign_out(self, session_id: object) -> Session | None:
        if not isinstance(session_id, str):
            return None
        return self._end(session_id)

    def _end_dead_sessions(self) -> None:
        """End expired sessions, and those whose token was revoked or changed role, so they take
        no room (the token check runs outside the lock: it may read the token file)."""
        if self._tokens is None:
            return
        now = self._clock()
        with self._lock:
            entries = list(self._sessions.values())
        for session, presented in entries:
            principal = None if now >= session.expires_mono else self._tokens.authenticate(presented)
            if principal is None or principal.role != session.role:
                self._end(session.session_id)

    def _end(self, session_id: str) -> Session | None:
        with self._lock:
            return self._end_locked(session_id)

    def _end_locked(self, session_id: str) -> Session | None:
        """End a session; its ticket is kept (bounded, per token name) for its page's E-STOP."""
        entry = self._sessions.pop(session_id, None)
        self._flashes.pop(session_id, None)
        if entry is None:
            return None
        session = entry[0]
        ended = self._ended.setdefault(session.name, OrderedDict())
        ended[session.estop_ticket] = None
        while len(ended) > MAX_ENDED_TICKETS_PER_PRINCIPAL:
            forgotten, _ = ended.popitem(last=False)
            self._tickets.pop(forgotten, None)
        return session

    def _ticket_for(self, session_id: str) -> str:
        mac = hmac.new(self._secret, b"console-estop\0" + session_id.encode(), hashlib.sha256).digest()
        return base64.urlsafe_b64encode(mac).decode().rstrip("=")


def _fingerprint(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()[:16]
