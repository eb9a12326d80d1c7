"""The hash chain: record fields, canonical JSON, SHA-256 or HMAC-SHA256, the key from the environment.

``hash`` = SHA-256 (HMAC-SHA256 when a key is configured) over the canonical JSON of the record
without ``hash``; the written line is the canonical JSON of the full record, so any byte edit
is detected.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import hmac as _hmac
import json
import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from armwarden.core.errors import ConfigurationError

AUDIT_KEY_ENV = "ARMWARDEN_AUDIT_KEY"
GENESIS_HASH = "0" * 64
RECORD_FIELDS: tuple[str, ...] = (
    "seq",
    "wall_time",
    "mono_time",
    "event",
    "session",
    "principal",
    "tool",
    "arguments",
    "outcome",
    "detail",
    "operator",
    "extra",
    "prev",
    "hash",
)
FIELD_SET = frozenset(RECORD_FIELDS)
RECOVERY_MARK = b'"event":"recovery"'

@dataclass(frozen=True)
class AuditRecord:
    """One audit record exactly as written (field order = `RECORD_FIELDS`)."""

    seq: int
    wall_time: str
    mono_time: float
    event: str
    session: str | None
    principal: str | None
    tool: str | None
    arguments: Any
    outcome: str | None
    detail: str | None
    operator: str | None
    extra: dict[str, Any] | None
    prev: str
    hash: str

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


_CANONICAL = json.JSONEncoder(sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def canonical_json(obj: Mapping[str, Any]) -> bytes:
    return _CANONICAL.encode(obj).encode("utf-8")


def with_hash(body_json: bytes, digest: str) -> bytes:
    """Canonical JSON of the full record from the canonical JSON of the record without ``hash``.

    Keys are sorted, so ``hash`` sits right before ``mono_time``; every top-level value after
    ``mono_time`` is a string, int or null, so the last ``,"mono_time":`` is the top-level key.
    """
    cut = body_json.rfind(b',"mono_time":')
    return b"".join((body_json[:cut], b',"hash":"', digest.encode("ascii"), b'"', body_json[cut:]))


def _reject_constant(name: str) -> Any:
    raise ValueError(f"non-strict JSON constant {name}")


DECODER = json.JSONDecoder(parse_constant=_reject_constant)  # strict: no NaN/Infinity


def digest(payload: bytes, key: bytes | None) -> str:
    if key is None:
        return hashlib.sha256(payload).hexdigest()
    return _hmac.new(key, payload, hashlib.sha256).hexdigest()


def utc_now() -> str:
    """UTC wall time as `YYYY-MM-DDTHH:MM:SS.ffffffZ` (isoformat is ~4x cheaper than strftime)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="microseconds")[:-6] + "Z"


def check_key(key: Any) -> bytes | None:
    if key is None:
        return None
    if not isinstance(key, (bytes, bytearray)):
        raise ConfigurationError("audit HMAC key must be bytes (see hmac_key_from_env)")
    if not key:
        raise ConfigurationError("audit HMAC key is empty; pass None for an unkeyed log")
    return bytes(key)


def hmac_key_from_env(environ: Mapping[str, str] = os.environ) -> bytes | None:
    """The audit HMAC key from ``ARMWARDEN_AUDIT_KEY`` (UTF-8 bytes); unset or empty → None."""
    value = environ.get(AUDIT_KEY_ENV)
    if not value:
        return None
    return value.encode("utf-8", "surrogateescape")


#: how a shell expression starts that a client passed on without expanding it
UNEXPANDED_PREFIXES = ("${", "$(")
#: an unexpanded reference a client passed on literally, wherever it is in the value: a complete
#: shell `${...}`/`$(...)` anywhere, `$NAME` at the start, or the whole value a Windows `%NAME%`.
#: A `$` or `%` otherwise (``pa$$word``, ``100%``, an unclosed ``${``) is part of a real key.
UNEXPANDED_REFERENCE = re.compile(r"\$\{[^}]*\}|\$\([^)]*\)|^\$[A-Za-z_]|^%[A-Za-z_][A-Za-z0-9_]*%\Z")


def _unexpanded_reason(value: str) -> str | None:
    """Why `value` looks like a reference to the key rather than the key, or None."""
    if value.startswith(UNEXPANDED_PREFIXES) or UNEXPANDED_REFERENCE.search(value):
        return "an unexpanded variable reference or shell expression"
    if value != value.strip():
        return ("a value with leading or trailing whitespace (a quoting slip, or an unexpanded reference "
                "with a space around it)")
    return None


def hmac_key_for_serving(environ: Mapping[str, str] = os.environ) -> bytes | None:
    """`hmac_key_from_env` for a daemon about to write a log: a value that is an unexpanded
    reference (``${ARMWARDEN_AUDIT_KEY:-}`` or ``$ARMWARDEN_AUDIT_KEY`` from a client config that
    a client such as the MCP Inspector does not expand, ``%ARMWARDEN_AUDIT_KEY%`` on Windows) or
    has whitespace around it is refused, not used as the key: such a key is public (anyone could
    re-chain the log with it), and every later `audit verify` with the real key fails."""
    value = environ.get(AUDIT_KEY_ENV, "")
    reason = _unexpanded_reason(value)
    if reason is not None:
        raise ConfigurationError(
            f"{AUDIT_KEY_ENV} is {value!r}, {reason}: the MCP client that started this daemon most likely "
            f"passed it on unexpanded. Set the key itself in the client's env, or leave {AUDIT_KEY_ENV} out "
            "for an unkeyed log"
        )
    return hmac_key_from_env(environ)
