"""Bearer tokens for the HTTP transport (docs/architecture.md, "Transports and access").

The token file holds one entry per token — name, role, SHA-256 of the token, creation time —
and never the token itself: a token is printed once by ``armwarden tokens add`` and is not
recoverable afterwards. JSON by default; a ``.yaml``/``.yml`` suffix selects YAML::

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
import contextlib
import datetime as _dt
import hashlib
import hmac
import json
import logging
import os
import re
import secrets
import stat
import sys
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

import yaml
from pydantic import AwareDatetime, BaseModel, ConfigDict, Field, ValidationError, model_validator

from armwarden.core.errors import ConfigurationError

try:  # POSIX advisory lock between concurrent `tokens add/revoke` runs.
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "ROLES",
    "TOKEN_PREFIX",
    "Principal",
    "Role",
    "TokenInfo",
    "TokenStore",
    "tokens_add_command",
    "tokens_list_command",
    "tokens_revoke_command",
]

logger = logging.getLogger(__name__)

#: observer: read and stop; operator: a human, every tool and the console's approving and releasing;
#: agent: an MCP client's token, every tool an operator may call but no console sign-in (so it can
#: never approve or release there what it asked for)
Role = Literal["observer", "operator", "agent"]
ROLES: tuple[str, ...] = get_args(Role)
TOKEN_PREFIX = "aw_"
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$"
FINGERPRINT_HEX_CHARS = 12
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


class TokenEntry(BaseModel):
    """One stored token."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=NAME_PATTERN, description="Unique label, e.g. 'alice-laptop'.")
    role: Role = Field(description="'observer' (introspect + perception), 'operator' (everything, a human) or "
                       "'agent' (the MCP tools of an operator, no console sign-in).")
    token_sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="Lower-case hex SHA-256 of the token.")
    created: AwareDatetime = Field(description="When the token was added (ISO 8601 with offset).")

    @property
    def fingerprint(self) -> str:
        return self.token_sha256[:FINGERPRINT_HEX_CHARS]


class TokenFile(BaseModel):
    """The whole token file."""

    model_config = ConfigDict(extra="forbid")

    version: Literal[1] = 1
    tokens: list[TokenEntry] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique(self) -> TokenFile:
        for attribute in ("name", "token_sha256"):
            seen: set[str] = set()
            for entry in self.tokens:
                value = getattr(entry, attribute)
                if value in seen:
                    shown = value if attribute == "name" else value[:FINGERPRINT_HEX_CHARS]
                    raise ValueError(f"duplicate {attribute} {shown!r}")
                seen.add(value)
        return self


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _is_yaml(path: Path) -> bool:
    return path.suffix.lower() in (".yaml", ".yml")


def _check_permissions(path: Path, st: os.stat_result) -> None:
    if os.name != "posix":  # pragma: no cover - permission bits are POSIX-only
        return
    if st.st_uid not in (os.geteuid(), 0):
        raise ConfigurationError(
            f"token file {path} belongs to user id {st.st_uid}, neither this server's ({os.geteuid()}) nor root; "
            f"whoever owns it can grant themselves access. Run: chown {os.geteuid()} {path}"
        )
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o022:
        raise ConfigurationError(
            f"token file {path} is writable by group or others (mode {mode:04o}); "
            f"anyone who can write it can grant themselves access. Run: chmod 600 {path}"
        )
    if mode & 0o044:
        logger.warning("token file %s is readable by group or others (mode %04o); chmod 600 recommended", path, mode)


def _signature(st: os.stat_result) -> tuple[int, ...]:
    """What tells a changed token file: its content (inode, size, modification time), and its
    mode and owner (change time), so a `chmod 600` after a refusal is picked up at once."""
    return (st.st_ino, st.st_dev, st.st_mtime_ns, st.st_size, st.st_ctime_ns, st.st_mode, st.st_uid)


def _read_file(path: Path) -> tuple[TokenFile, tuple[int, ...]]:
    """Read and validate `path`; raise ConfigurationError with every problem listed."""
    try:
        with open(path, "rb") as handle:
            st = os.fstat(handle.fileno())
            _check_permissions(path, st)
            raw = handle.read()
    except FileNotFoundError:
        raise ConfigurationError(f"token file {path} does not exist (create it with 'armwarden tokens add')") from None
    except OSError as exc:
        raise ConfigurationError(f"cannot read token file {path}: {exc.strerror or exc}") from exc
    try:
        data: Any = yaml.safe_load(raw) if _is_yaml(path) else json.loads(raw)
    except (yaml.YAMLError, ValueError) as exc:
        kind = "YAML" if _is_yaml(path) else "JSON"
        raise ConfigurationError(f"token file {path} is not valid {kind}: {exc}") from exc
    try:
        content = TokenFile.model_validate(data)
    except ValidationError as exc:
        lines = "\n".join(
            f"  {'.'.join(str(part) for part in error['loc']) or '<root>'}: {error['msg']}" for error in exc.errors()
        )
        raise ConfigurationError(f"invalid token file {path}:\n{lines}") from None
    return content, _signature(st)


def _write_file(path: Path, content: TokenFile) -> None:
    """Atomically replace `path` with `content`, mode 0600."""
    data = content.model_dump(mode="json")
    text = yaml.safe_dump(data, sort_keys=False) if _is_yaml(path) else json.dumps(data, indent=2) + "\n"
    # mkstemp creates the file with mode 0600, so the token hashes are never briefly exposed.
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise
    with contextlib.suppress(OSError):  # make the rename durable
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Exclusive advisory lock for a read-modify-write of `path` (no-op where fcntl is missing)."""
    lock_path = path.parent / f".{path.name}.lock"
    try:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o600)
    except OSError as exc:
        raise ConfigurationError(f"cannot create lock file {lock_path}: {exc.strerror or exc}") from exc
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


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
        self._signature = signature
        self._lock = threading.Lock()

    # ---------------------------------------------------------------- loading / authentication
    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> TokenStore:
        """Load and validate the token file; `ConfigurationError` lists every problem."""
        file_path = Path(path)
        content, signature = _read_file(file_path)
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
                current = _signature(os.stat(self.path))
            except OSError:
                current = None
            if current == self._signature:
                return
            try:
                content, current = _read_file(self.path)
            except ConfigurationError as exc:
                logger.error("token file changed and cannot be used; refusing every token: %s", exc)
                self._entries, self._signature, self._unusable = (), current, True
                return
            logger.info("token file %s changed: %d token(s) now valid", self.path, len(content.tokens))
            self._entries, self._signature, self._unusable = tuple(content.tokens), current, False
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
        with _locked(path):
            content = _read_file(path)[0] if path.exists() else TokenFile()
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
            _write_file(path, TokenFile(tokens=[*content.tokens, entry]))
        return token, entry

    @classmethod
    def list(cls, path: str | os.PathLike[str]) -> builtins.list[TokenInfo]:
        """Name, role, creation time and hash fingerprint of every token, in file order."""
        content, _ = _read_file(Path(path))
        return [TokenInfo(e.name, e.role, e.created, e.fingerprint) for e in content.tokens]

    @classmethod
    def revoke(cls, path: str | os.PathLike[str], name: str) -> bool:
        """Remove the token called `name`; False if there is none."""
        file_path = Path(path)
        with _locked(file_path):
            content, _ = _read_file(file_path)
            kept = [entry for entry in content.tokens if entry.name != name]
            if len(kept) == len(content.tokens):
                return False
            _write_file(file_path, TokenFile(tokens=kept))
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
