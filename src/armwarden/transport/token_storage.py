"""The token file on disk: its format, and reading and writing it safely.

One entry per token — name, role, SHA-256 of the token, creation time — never the token itself.
JSON by default; a ``.yaml``/``.yml`` suffix selects YAML. Reading is strict (pydantic, unknown
keys, duplicate names or hashes refused) and refuses a file that group or others may write or that
another user owns; writing is atomic, mode 0600, and serialised between processes by `locked`.
`TokenStore` (`tokens.py`) builds on these; `file_signature` tells it when to re-read.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import stat
import tempfile
from collections.abc import Iterator
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
    "FINGERPRINT_HEX_CHARS",
    "NAME_PATTERN",
    "ROLES",
    "Role",
    "TokenEntry",
    "TokenFile",
    "file_signature",
    "hash_token",
    "locked",
    "read_tokens",
    "write_tokens",
]

logger = logging.getLogger(__name__)

#: observer: read and stop; operator: a human, every tool and the console's approving and releasing;
#: agent: an MCP client's token, every tool an operator may call but no console sign-in (so it can
#: never approve or release there what it asked for)
Role = Literal["observer", "operator", "agent"]
ROLES: tuple[str, ...] = get_args(Role)
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$"
FINGERPRINT_HEX_CHARS = 12


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


def file_signature(st: os.stat_result) -> tuple[int, ...]:
    """What tells a changed token file: its content (inode, size, modification time), and its
    mode and owner (change time), so a `chmod 600` after a refusal is picked up at once."""
    return (st.st_ino, st.st_dev, st.st_mtime_ns, st.st_size, st.st_ctime_ns, st.st_mode, st.st_uid)


def read_tokens(path: Path) -> tuple[TokenFile, tuple[int, ...]]:
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
    return content, file_signature(st)


def write_tokens(path: Path, content: TokenFile) -> None:
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
def locked(path: Path) -> Iterator[None]:
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
