"""Bearer tokens for the HTTP transport (docs/architecture.md, "Transports and access").

The token file holds one entry per token — name, role, SHA-256 of the token, creation time —
and never the token itself: a token is printed once by ``armwarden tokens add`` and is not
recoverable afterwards. JSON by default; a ``.yaml``/``.yml`` suffix selects YAML (its format,
reading and writing: `token_storage.py`)::

    {"version": 1,
     "tokens": [{"name": "alice", "role": "operator",
                 "token_sha256": "9f86d0…", "created": "2025-01-01T12:00:00+00:00"}]}

Rules
- Loading is strict (pydantic, unknown keys refused, duplicate names or hashes refused) and
  refuses a file that group or others may write (anyone who can write it can add themselves);
  a file that group or others may read is accepted with a warning (256-bit tokens are not
  guessable from their hashes, but there is no reason to expose them).
- Writes are atomic (temporary file + ``os.replace``), always mode 0600, and serialised between
  processes by an advisory lock on a sidecar ``.<name>.lock`` file, so a concurrent ``add``
  cannot resurrect a token that a ``revoke`` just removed.
- A loaded `TokenStore` re-reads its file when the file changes (checked on every
  `TokenStore.authenticate`), so ``armwarden tokens revoke`` takes effect without a restart.
  If the file becomes unreadable or invalid the store fails closed: no token authenticates
  until the file is fixed.
- `TokenStore.authenticate` hashes the presented token once and compares the digest with every
  stored hash using `hmac.compare_digest`, without stopping at the first match.
"""

from __future__ import annotations

import builtins
import datetime as _dt
import hmac
import logging
import os
import re
import secrets
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from armwarden.core.errors import ConfigurationError
from armwarden.transport.token_storage import (
    NAME_PATTERN,
    ROLES,
    Role,
    TokenEntry,
    TokenFile,
    file_signature,
    hash_token,
    locked,
    read_tokens,
    write_tokens,
)

__all__ = [
    "TOKEN_PREFIX",
    "Principal",
    "TokenInfo",
    "TokenStore",
    "tokens_add_command",
    "tokens_list_command",
    "tokens_revoke_command",
]

logger = logging.getLogger(__name__)

TOKEN_PREFIX = "aw_"
MAX_PRESENTED_TOKEN_CHARS = 512
"""Longer presented tokens are rejected before hashing (ours are 46 characters)."""


@dataclass(frozen=True)
class Principal:
    """Who is calling: the token's name and its role."""

    name: str
    role: Role


@dataclass(frozen=True)
class TokenInfo:
    """What `TokenStore.list` shows about a token: never the token, only a short hash prefix."""

    name: str
    role: Role
    created: _dt.datetime
    fingerprint: str


def _check_role(role: str) -> Role:
    if role not in ROLES:
        raise ConfigurationError(f"unknown role {role!r}; valid roles: {', '.join(ROLES)}")
    return role  # type: ignore[return-value]


class TokenStore:
    """The tokens of one file, loaded for authentication; class methods edit the file."""

    def __init__(self, path: Path, content: TokenFile, signature: tuple[int, ...] | None) -> None:
        self.path = path
        self._entries: tuple[TokenEntry, ...] = tuple(content.tokens)
        #: the tokens of the last version of the file that could be used (see `authenticate`)
        self._last_good: tuple[TokenEntry, ...] = self._entries
        self._unusable = False
        self.file_signature = signature
        self._lock = threading.Lock()

    # ---------------------------------------------------------------- loading / authentication
    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> TokenStore:
        """Load and validate the token file; `ConfigurationError` lists every problem."""
        file_path = Path(path)
        content, signature = read_tokens(file_path)
        if not content.tokens:
            logger.warning("token file %s holds no tokens: every HTTP request will be refused", file_path)
        return cls(file_path, content, signature)

    def __len__(self) -> int:
        self._refresh()
        return len(self._entries)

    def authenticate(self, presented: str, *, last_good_while_unusable: bool = False) -> Principal | None:
        """The principal of `presented`, or None. Constant time in the position of the match.

        While the file is unusable (deleted, invalid, writable by others) every token is refused,
        unless `last_good_while_unusable`: the e-stop channel must not refuse a stop because the
        token file broke, so it keeps the tokens of the last usable version (a revocation written to
        a usable file still takes effect at once)."""
        self._refresh()
        if not presented or len(presented) > MAX_PRESENTED_TOKEN_CHARS:
            return None
        digest = hash_token(presented)
        found: TokenEntry | None = None
        entries = self._last_good if last_good_while_unusable and self._unusable else self._entries
        for entry in entries:  # no early exit: every stored hash is compared
            if hmac.compare_digest(entry.token_sha256, digest):
                found = entry
        return None if found is None else Principal(name=found.name, role=found.role)

    def _refresh(self) -> None:
        """Re-read the file if it changed since it was loaded; fail closed if it became invalid."""
        with self._lock:
            try:
                current = file_signature(os.stat(self.path))
            except OSError:
                current = None
            if current == self.file_signature:
                return
            try:
                content, current = read_tokens(self.path)
            except ConfigurationError as exc:
                logger.error("token file changed and cannot be used; refusing every token: %s", exc)
                self._entries, self.file_signature, self._unusable = (), current, True
                return
            logger.info("token file %s changed: %d token(s) now valid", self.path, len(content.tokens))
            self._entries, self.file_signature, self._unusable = tuple(content.tokens), current, False
            self._last_good = self._entries

    # ---------------------------------------------------------------- editing the file
    @classmethod
    def add(cls, path: str | os.PathLike[str], role: str, name: str | None = None) -> str:
        """Add a new token with `role`; create the file (mode 0600) if missing. Returns the token."""
        return cls._add(Path(path), role, name)[0]

    @classmethod
    def _add(cls, path: Path, role: str, name: str | None) -> tuple[str, TokenEntry]:
        checked_role = _check_role(role)
        if name is not None and not re.fullmatch(NAME_PATTERN, name):
            raise ConfigurationError(
                f"invalid token name {name!r}: 1-64 characters from A-Z a-z 0-9 . _ @ -, starting alphanumeric"
            )
        with locked(path):
            content = read_tokens(path)[0] if path.exists() else TokenFile()
            names = {entry.name for entry in content.tokens}
            if name is None:
                candidates = (f"{checked_role}-{k}" for k in range(1, len(names) + 2))
                name = next(candidate for candidate in candidates if candidate not in names)
            elif name in names:
                raise ConfigurationError(f"a token named {name!r} already exists in {path}; revoke it first")
            token = TOKEN_PREFIX + secrets.token_urlsafe(32)
            entry = TokenEntry(
                name=name,
                role=checked_role,
                token_sha256=hash_token(token),
                created=_dt.datetime.now(_dt.timezone.utc).replace(microsecond=0),
            )
            write_tokens(path, TokenFile(tokens=[*content.tokens, entry]))
        return token, entry

    @classmethod
    def list(cls, path: str | os.PathLike[str]) -> builtins.list[TokenInfo]:
        """Name, role, creation time and hash fingerprint of every token, in file order."""
        content, _ = read_tokens(Path(path))
        return [TokenInfo(e.name, e.role, e.created, e.fingerprint) for e in content.tokens]

    @classmethod
    def revoke(cls, path: str | os.PathLike[str], name: str) -> bool:
        """Remove the token called `name`; False if there is none."""
        file_path = Path(path)
        with locked(file_path):
            content, _ = read_tokens(file_path)
            kept = [entry for entry in content.tokens if entry.name != name]
            if len(kept) == len(content.tokens):
                return False
            write_tokens(file_path, TokenFile(tokens=kept))
        return True


# -------------------------------------------------------------------- CLI handlers
def _fail(exc: Exception) -> int:
    print(f"armwarden: error: {exc}", file=sys.stderr)
    return 2


def tokens_add_command(path: str | os.PathLike[str], role: str, name: str | None = None) -> int:
    """`armwarden tokens add FILE --role R [--name N]`: print the new token once on stdout."""
    try:
        token, added = TokenStore._add(Path(path), role, name)
    except ConfigurationError as exc:
        return _fail(exc)
    print(
        f"armwarden: added {added.role} token {added.name!r} to {path}; "
        "it is shown only this once and cannot be recovered - store it now.",
        file=sys.stderr,
    )
    print(token, flush=True)
    return 0


def tokens_list_command(path: str | os.PathLike[str]) -> int:
    """`armwarden tokens list FILE`: one line per token, never the token itself."""
    try:
        infos = TokenStore.list(path)
    except ConfigurationError as exc:
        return _fail(exc)
    if not infos:
        print(f"armwarden: no tokens in {path}", file=sys.stderr)
        return 0
    width = max(len("NAME"), *(len(info.name) for info in infos))
    print(f"{'NAME':<{width}}  {'ROLE':<8}  {'CREATED':<25}  FINGERPRINT")
    for info in infos:
        print(f"{info.name:<{width}}  {info.role:<8}  {info.created.isoformat():<25}  sha256:{info.fingerprint}")
    return 0


def tokens_revoke_command(path: str | os.PathLike[str], name: str) -> int:
    """`armwarden tokens revoke FILE NAME`: 0 if revoked, 1 if no such token, 2 on a bad file."""
    try:
        revoked = TokenStore.revoke(path, name)
    except ConfigurationError as exc:
        return _fail(exc)
    if not revoked:
        print(f"armwarden: no token named {name!r} in {path}", file=sys.stderr)
        return 1
    print(f"armwarden: revoked token {name!r}; running servers stop accepting it at the next request", file=sys.stderr)
    return 0
