"""Append-only, hash-chained JSONL audit log (design §4 "Audit log", principle 5).

One record per line, written with a single ``write`` and ``fsync``-ed before `AuditLog.append`
returns. Every record carries ``prev`` (the previous record's ``hash``; 64 zeros for the first)
and ``hash`` = SHA-256 — or HMAC-SHA256 when a key is configured — over the canonical JSON of
the record without ``hash``::

    json.dumps(record_without_hash, sort_keys=True, separators=(",", ":"),
               ensure_ascii=False).encode("utf-8")

The line itself is the canonical JSON of the full record, so *any* byte edit is detected.

Crash handling. A crash can leave a torn last line (no trailing newline, or not JSON). On open
the log never rewrites history: it terminates the fragment with a newline and appends a
``recovery`` record, chained from the last good record, whose ``extra`` names the fragment
(``torn_line``, ``torn_bytes``, ``torn_sha256``). `verify_file` accepts exactly that fragment and
lists it in ``recovered_lines``. Anything else that does not verify — a corrupt line that is not
the last one, a valid-JSON last line whose chain is broken — makes the open fail with
`ConfigurationError` naming the first bad line: the operator must move the file aside.

Limits of the scheme: without an HMAC key anybody with write access can recompute a whole
chain, so only the keyed mode detects forgery; removing whole records from the *end* of the file
is not detectable from the file alone (compare `seq` against an external copy of the tail).
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import decimal
import enum
import errno
import functools
import hashlib
import hmac as _hmac
import itertools
import json
import math
import os
import queue
import stat
import sys
import threading
import time
import uuid
from collections import deque
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import IO, Any


from armwarden.errors import ArmWardenError, ConfigurationError

try:  # POSIX advisory lock: one writer per log file.
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "AUDIT_KEY_ENV",
    "GENESIS_HASH",
    "RECORD_FIELDS",
    "AuditLog",
    "AuditRecord",
    "AuditWriteError",
    "VerifyReport",
    "hmac_key_from_env",
    "read_tail",
    "sanitize",
    "tail_command",
    "verify_command",
    "verify_file",
]

AUDIT_KEY_ENV = "ARMWARDEN_AUDIT_KEY"
GENESIS_HASH = "0" * 64
MAX_EVENT_CHARS = 64
MAX_TAIL = 1000

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
_FIELD_SET = frozenset(RECORD_FIELDS)
_RECOVERY_MARK = b'"event":"recovery"'


class AuditWriteError(ArmWardenError):
    """A record could not be made durable (log closed, disk error). Callers must fail closed."""


# --------------------------------------------------------------------------------------------
# Sanitising
# --------------------------------------------------------------------------------------------

_IMAGE_KEYS = frozenset({"image", "png", "jpeg", "jpg", "image_bytes", "image_data", "image_base64"})
_IMAGE_KEY_MIN_CHARS = 64  # shorter strings under an image-ish key are names, not pixels


class _Sanitizer:
    __slots__ = ("max_chars", "max_depth", "max_items", "budget")

    def __init__(self, max_chars: int, max_depth: int, max_items: int, max_nodes: int) -> None:
        self.max_chars = max(1, int(max_chars))
        self.max_depth = max(1, int(max_depth))
        self.max_items = max(1, int(max_items))
        self.budget = max(1, int(max_nodes))

    # -- scalars ---------------------------------------------------------------------------
    def text(self, s: str, limit: int | None = None) -> str:
        limit = self.max_chars if limit is None else limit
        s = str.__str__(s)  # plain str even for subclasses with a hostile __str__
        n = len(s)
        if n > limit:
            s = s[:limit]
        try:
            s.encode("utf-8")
        except UnicodeEncodeError:  # lone surrogates cannot be written as UTF-8
            s = s.encode("utf-8", "replace").decode("utf-8")
        if n > limit:
            s = f"{s}…[truncated {n - limit} chars]"
        return s

    @staticmethod
    def redacted(value: Any) -> str:
        try:
            if isinstance(value, memoryview):
                size = value.nbytes
            elif isinstance(value, str):
                size = len(value)
            else:
                size = len(value)
        except Exception:
            size = -1
        return f"<redacted {size} bytes>" if size >= 0 else "<redacted>"

    @staticmethod
    def type_name(value: Any) -> str:
        try:
            name = type(value).__qualname__
            return name if isinstance(name, str) else "object"
        except Exception:
            return "object"

    def repr_of(self, value: Any) -> str:
        try:
            r = repr(value)
            if not isinstance(r, str):
                raise TypeError
        except Exception:
            return f"<unrepresentable {self.type_name(value)}>"
        return self.text(r)

    # -- walk ------------------------------------------------------------------------------
    def walk(self, v: Any, depth: int) -> Any:
        try:
            return self._walk(v, depth)
        except Exception:  # never raise, whatever the object does
            return f"<unserializable {self.type_name(v)}>"

    def _walk(self, v: Any, depth: int) -> Any:
        self.budget -= 1
        if self.budget < 0:
            return "…[omitted: record size limit]"
        if v is None or v is True or v is False:
            return v
        if isinstance(v, bool):
            return bool(v)
        if isinstance(v, float):
            f = float.__float__(v)
            if math.isnan(f):
                return "nan"
            if math.isinf(f):
                return "inf" if f > 0 else "-inf"
            return f
        if isinstance(v, int):
            n = int.__index__(v)
            if n.bit_length() <= 128:
                return n
            return f"<int with {n.bit_length()} bits>"
        if isinstance(v, str):
            if v.startswith("data:image/"):
                return self.redacted(v)
            return self.text(v)
        if isinstance(v, (bytes, bytearray, memoryview)):
            return self.redacted(v)
        if isinstance(v, enum.Enum):
            return self.walk(v.value, depth)
        if isinstance(v, (_dt.datetime, _dt.date, _dt.time)):
            return self.text(v.isoformat())
        if isinstance(v, (uuid.UUID, decimal.Decimal)):
            return self.text(str(v))
        if isinstance(v, os.PathLike):
            p = os.fspath(v)
            return self.text(p) if isinstance(p, str) else self.redacted(p)
        if depth >= self.max_depth:
            return "…[max depth reached]"
        if isinstance(v, Mapping):
            return self.mapping(v, depth)
        if isinstance(v, (list, tuple, set, frozenset, deque)):
            return self.sequence(v, depth)
        return self.other(v, depth)

    def sequence(self, v: Any, depth: int) -> list[Any]:
        out: list[Any] = []
        total = len(v)
        for item in itertools.islice(v, self.max_items):
            if self.budget <= 0:
                break
            out.append(self.walk(item, depth + 1))
        if len(out) < total:
            out.append(f"…[{total - len(out)} more items]")
        return out

    def key(self, k: Any) -> str:
        if isinstance(k, str):
            return self.text(k)
        if k is None or isinstance(k, (bool, int, float)):
            s = self.walk(k, self.max_depth)
            return s if isinstance(s, str) else json.dumps(s)
        return self.repr_of(k)

    def mapping(self, v: Mapping[Any, Any], depth: int) -> dict[str, Any]:
        try:
            kind = v.get("type")
            mime = v.get("mimeType", v.get("mime_type"))
        except Exception:
            kind = mime = None
        image_dict = kind == "image" or (isinstance(mime, str) and mime.startswith("image/"))
        out: dict[str, Any] = {}
        total = len(v)
        taken = 0
        for k, val in itertools.islice(v.items(), self.max_items):
            if self.budget <= 0:
                break
            taken += 1
            key = self.key(k)
            base, n = key, 2
            while key in out:
                key, n = f"{base}#{n}", n + 1
            lowered = key.lower()
            if isinstance(val, (bytes, bytearray, memoryview)) or (
                isinstance(val, str)
                and (
                    (image_dict and lowered == "data")
                    or (lowered in _IMAGE_KEYS and len(val) >= _IMAGE_KEY_MIN_CHARS)
                )
            ):
                self.budget -= 1
                out[key] = self.redacted(val)
            else:
                out[key] = self.walk(val, depth + 1)
        if taken < total:
            out["…"] = f"[{total - taken} more keys]"
        return out

    def other(self, v: Any, depth: int) -> Any:
        mod = getattr(type(v), "__module__", "") or ""
        if mod.startswith("numpy"):
            dtype = getattr(v, "dtype", None)
            size = getattr(v, "size", 1)
            ndim = getattr(v, "ndim", 0)
            if ndim >= 2 and str(dtype) == "uint8":  # pixels
                return f"<redacted {int(getattr(v, 'nbytes', size))} bytes>"
            if ndim == 0 and hasattr(v, "item"):
                return self.walk(v.item(), depth)
            if isinstance(size, int) and size <= self.max_items * 4 and hasattr(v, "tolist"):
                return self.walk(v.tolist(), depth)
            return self.text(f"<ndarray shape={getattr(v, 'shape', '?')} dtype={dtype}>")
        dump = getattr(v, "model_dump", None)  # pydantic models (e.g. MCP ImageContent)
        if callable(dump) and not isinstance(v, type):
            return self.walk(dump(mode="python"), depth)
        if is_dataclass(v) and not isinstance(v, type):
            return self.walk({f.name: getattr(v, f.name, None) for f in fields(v)}, depth)
        return self.repr_of(v)


def sanitize(
    value: Any,
    *,
    max_string_chars: int = 500,
    max_depth: int = 8,
    max_items: int = 200,
    max_nodes: int = 2000,
) -> Any:
    """Return a strict-JSON-safe copy of ``value``; pure, never raises.

    Strings longer than ``max_string_chars`` are cut with ``…[truncated N chars]``; bytes and
    image payloads become ``"<redacted N bytes>"``; NaN/±Inf become ``"nan"``/``"inf"``/``"-inf"``;
    containers deeper than ``max_depth`` or longer than ``max_items`` are cut with a marker; the
    whole value is bounded by ``max_nodes``; unknown objects become their (truncated) ``repr``.
    """
    try:
        return _Sanitizer(max_string_chars, max_depth, max_items, max_nodes).walk(value, 0)
    except BaseException as exc:  # noqa: BLE001 - documented: never raises (bar interrupts)
        if isinstance(exc, (KeyboardInterrupt, SystemExit, GeneratorExit)):
            raise
        return "<unserializable>"


# --------------------------------------------------------------------------------------------
# Records and hashing
# --------------------------------------------------------------------------------------------


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


def _canonical(obj: Mapping[str, Any]) -> bytes:
    return _CANONICAL.encode(obj).encode("utf-8")


def _with_hash(body_json: bytes, digest: str) -> bytes:
    """Canonical JSON of the full record from the canonical JSON of the record without ``hash``.

    Keys are sorted, so ``hash`` sits right before ``mono_time``; every top-level value after
    ``mono_time`` is a string, int or null, so the last ``,"mono_time":`` is the top-level key.
    """
    cut = body_json.rfind(b',"mono_time":')
    return b"".join((body_json[:cut], b',"hash":"', digest.encode("ascii"), b'"', body_json[cut:]))


def _reject_constant(name: str) -> Any:
    raise ValueError(f"non-strict JSON constant {name}")


_DECODER = json.JSONDecoder(parse_constant=_reject_constant)  # strict: no NaN/Infinity


def _digest(payload: bytes, key: bytes | None) -> str:
    if key is None:
        return hashlib.sha256(payload).hexdigest()
    return _hmac.new(key, payload, hashlib.sha256).hexdigest()


def _utc_now() -> str:
    """UTC wall time as `YYYY-MM-DDTHH:MM:SS.ffffffZ` (isoformat is ~4x cheaper than strftime)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="microseconds")[:-6] + "Z"


def _check_key(key: Any) -> bytes | None:
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


# --------------------------------------------------------------------------------------------
# Verification
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class VerifyReport:
    ok: bool
    records: int
    first_bad_line: int | None
    reason: str | None
    recovered_lines: list[int] = field(default_factory=list)


@dataclass
class _Scan:
    """Result of walking a log: the report plus what a writer needs to continue the chain."""

    report: VerifyReport
    last_seq: int
    last_hash: str
    bad_is_last: bool = False  # the first bad line is the file's last line
    bad_parses: bool = False  # ...and it is a JSON object (so not a torn write)
    bad_bytes: bytes = b""  # its content without the newline


def _check_line(
    content: bytes, expected_seq: int, prev_hash: str, key: bytes | None
) -> tuple[dict[str, Any] | None, str | None, bool]:
    """Validate one newline-stripped line. Returns (record, failure reason, parsed as object)."""
    try:
        obj = _DECODER.decode(content.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None, "invalid JSON", False
    if not isinstance(obj, dict):
        return None, "not a JSON object", False
    keys = set(obj)
    if keys != _FIELD_SET:
        missing = sorted(_FIELD_SET - keys)
        unknown = sorted(keys - _FIELD_SET)
        what = f"missing field(s) {missing}" if missing else f"unknown field(s) {unknown}"
        return None, what, True
    claimed = obj["hash"]
    body = {k: v for k, v in obj.items() if k != "hash"}
    try:
        body_json = _canonical(body)
    except (ValueError, TypeError, UnicodeEncodeError):
        return None, "hash mismatch", True
    expected = _digest(body_json, key)
    if not isinstance(claimed, str) or not _hmac.compare_digest(claimed, expected):
        return None, "hash mismatch", True
    if content != _with_hash(body_json, expected):
        return None, "line is not in canonical form", True
    seq = obj["seq"]
    if type(seq) is not int or seq != expected_seq:
        return None, f"sequence break: expected seq {expected_seq}, found {seq!r}", True
    if obj["prev"] != prev_hash:
        return None, "prev does not link to the previous record's hash", True
    if not isinstance(obj["event"], str) or not obj["event"]:
        return None, "event is not a non-empty string", True
    return obj, None, True


def _fragment_claim(next_content: bytes, lineno: int) -> dict[str, Any] | None:
    """If the next line is a recovery record naming line ``lineno`` as torn, return its extra."""
    if _RECOVERY_MARK not in next_content:
        return None
    try:
        obj = _DECODER.decode(next_content.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None
    if not isinstance(obj, dict) or obj.get("event") != "recovery":
        return None
    extra = obj.get("extra")
    if isinstance(extra, dict) and type(extra.get("torn_line")) is int and extra["torn_line"] == lineno:
        return extra
    return None


def _scan(stream: IO[bytes], key: bytes | None) -> _Scan:
    lines = enumerate(stream, start=1)  # binary iteration splits on b"\n" only
    records = 0
    last_seq, last_hash = 0, GENESIS_HASH
    recovered: list[int] = []

    def fail(lineno: int, reason: str, is_last: bool, parses: bool, content: bytes) -> _Scan:
        return _Scan(
            VerifyReport(False, records, lineno, reason, list(recovered)),
            last_seq,
            last_hash,
            bad_is_last=is_last,
            bad_parses=parses,
            bad_bytes=content,
        )

    cur = next(lines, None)
    while cur is not None:
        nxt = next(lines, None)
        lineno, raw = cur
        terminated = raw.endswith(b"\n")
        content = raw[:-1] if terminated else raw
        claim = _fragment_claim(nxt[1].rstrip(b"\n"), lineno) if nxt is not None else None
        if claim is not None:
            if claim.get("torn_bytes") != len(content) or claim.get(
                "torn_sha256"
            ) != hashlib.sha256(content).hexdigest():
                return fail(lineno, "fragment does not match its recovery record", False, False, content)
            recovered.append(lineno)
            cur = nxt
            continue
        if not terminated:  # only the last line can lack its newline
            return fail(lineno, "torn last line", True, False, content)
        obj, reason, parses = _check_line(content, last_seq + 1, last_hash, key)
        if reason is not None:
            return fail(lineno, reason, nxt is None, parses, content)
        assert obj is not None
        records += 1
        last_seq, last_hash = obj["seq"], obj["hash"]
        cur = nxt
    return _Scan(VerifyReport(True, records, None, None, recovered), last_seq, last_hash)


def verify_file(path: str | os.PathLike[str], hmac_key: bytes | None = None) -> VerifyReport:
    """Check every line of the log at ``path``: parse, seq +1, prev link, hash, canonical form.

    A torn last line is reported (``reason == "torn last line"``); a fragment that a following
    ``recovery`` record names exactly (line number, byte length, SHA-256) is accepted and listed
    in ``recovered_lines``. Raises OSError if the file cannot be read.
    """
    key = _check_key(hmac_key)
    with open(path, "rb") as stream:
        return _scan(stream, key).report


# --------------------------------------------------------------------------------------------
# Tail
# --------------------------------------------------------------------------------------------


def _clamp_tail(n: Any) -> int:
    try:
        n = int(n)
    except (TypeError, ValueError):
        n = 1
    return min(max(n, 1), MAX_TAIL)


def _tail_lines(stream: IO[bytes], n: int, block: int = 65536) -> list[bytes]:
    stream.seek(0, os.SEEK_END)
    pos = stream.tell()
    buf = b""
    while pos > 0 and buf.count(b"\n") <= n:
        step = min(block, pos)
        pos -= step
        stream.seek(pos)
        buf = stream.read(step) + buf
    lines = buf.split(b"\n")
    if pos > 0:
        lines = lines[1:]  # first piece may be a partial line
    return [line for line in lines if line.strip()][-n:]


def read_tail(path: str | os.PathLike[str], n: int = 20) -> list[dict[str, Any]]:
    """The last ``n`` (clamped to 1..1000) parseable records of the log at ``path``, oldest first.

    Lines that are not JSON objects (a torn fragment) are skipped, not returned.
    """
    n = _clamp_tail(n)
    out: list[dict[str, Any]] = []
    with open(path, "rb") as stream:
        for line in _tail_lines(stream, n):
            try:
                obj = _DECODER.decode(line.decode("utf-8"))
            except (UnicodeDecodeError, ValueError, RecursionError):
                continue
            if isinstance(obj, dict):
                out.append(obj)
    return out


# --------------------------------------------------------------------------------------------
# The log
# --------------------------------------------------------------------------------------------



class AuditLog:
    """The daemon's audit log. Thread-safe; one writer process per file (advisory lock).

    ``append`` returns only after the record is written and fsync-ed. Use ``append_async`` from
    the event loop: it runs ``append`` in a worker thread (FIFO per log and event loop), so the
    loop never waits for the disk.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        hmac_key: bytes | None = None,
        max_string_chars: int = 500,
    ) -> None:
        self._path = Path(path)
        self._key = _check_key(hmac_key)
        if isinstance(max_string_chars, bool) or not isinstance(max_string_chars, int) or not (
            16 <= max_string_chars <= 1_000_000
        ):
            raise ConfigurationError(
                f"audit max_string_chars must be an int in 16..1000000, got {max_string_chars!r}"
            )
        self._max_chars = max_string_chars
        self._texter = _Sanitizer(max_string_chars, 1, 1, 1)  # text() only; stateless
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue | None = None  # jobs for the writer thread (started on first use)
        self._thread: threading.Thread | None = None
        self._fd: int | None = None
        self._broken: str | None = None
        self._seq = 0
        self._prev = GENESIS_HASH
        self._recovery: AuditRecord | None = None
        self._open()

    # -- opening ---------------------------------------------------------------------------
    def _open(self) -> None:
        path = self._path
        parent = path.parent
        if not parent.is_dir():
            raise ConfigurationError(
                f"audit log directory {str(parent)!r} does not exist (create it; it is not created for you)"
            )
        created = not path.exists()
        try:
            fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o600)
        except OSError as exc:
            raise ConfigurationError(f"cannot open audit log {str(path)!r}: {exc.strerror or exc}") from exc
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise ConfigurationError(f"audit log {str(path)!r} is not a regular file")
            if fcntl is not None:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as exc:
                    if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                        raise ConfigurationError(
                            f"audit log {str(path)!r} is already open by another writer"
                        ) from exc
                    raise
            if created:
                _fsync_dir(parent)
            with os.fdopen(os.dup(fd), "rb") as stream:
                stream.seek(0)
                scan = _scan(stream, self._key)
            self._fd = fd
            self._seq, self._prev = scan.last_seq, scan.last_hash
            report = scan.report
            if not report.ok:
                assert report.first_bad_line is not None
                torn = scan.bad_is_last and (report.reason == "torn last line" or not scan.bad_parses)
                if not torn:
                    raise ConfigurationError(
                        f"audit log {str(path)!r} does not verify: line {report.first_bad_line}: "
                        f"{report.reason}. Refusing to continue a damaged chain; move the file "
                        f"aside (and keep it for investigation), then start again."
                    )
                self._recover(report.first_bad_line, scan.bad_bytes)
        except BaseException as exc:
            self._fd = None
            os.close(fd)
            if isinstance(exc, OSError):
                raise ConfigurationError(f"cannot use audit log {str(path)!r}: {exc}") from exc
            raise

    def _recover(self, lineno: int, fragment: bytes) -> None:
        """Terminate a torn last line (if needed) and chain a recovery record past it."""
        record, line = self._build(
            "recovery",
            detail=f"torn last line {lineno} ({len(fragment)} bytes) from an interrupted write; "
            "left in place, chain continues from the last good record",
            outcome="recovered",
            extra={
                "torn_line": lineno,
                "torn_bytes": len(fragment),
                "torn_sha256": hashlib.sha256(fragment).hexdigest(),
            },
        )
        assert self._fd is not None
        size = os.fstat(self._fd).st_size
        needs_newline = size > 0 and _last_byte(self._fd, size) != b"\n"
        try:
            self._write((b"\n" if needs_newline else b"") + line)
        except OSError as exc:
            raise ConfigurationError(
                f"cannot write the recovery record to audit log {str(self._path)!r}: {exc}"
            ) from exc
        self._seq, self._prev = record.seq, record.hash
        self._recovery = record

    # -- properties ------------------------------------------------------------------------
    @property
    def path(self) -> Path:
        return self._path

    @property
    def closed(self) -> bool:
        return self._fd is None

    @property
    def last_seq(self) -> int:
        return self._seq

    @property
    def last_hash(self) -> str:
        return self._prev

    @property
    def broken(self) -> str | None:
        """Why the log refuses appends after a failed write (None while it is healthy)."""
        return self._broken

    @property
    def recovery_record(self) -> AuditRecord | None:
        """The recovery record written on open, if the file ended with a torn line."""
        return self._recovery

    # -- writing ---------------------------------------------------------------------------
    def _text_field(self, value: Any) -> str | None:
        if value is None:
            return None
        if not isinstance(value, str):
            value = sanitize(value, max_string_chars=self._max_chars)
            if not isinstance(value, str):
                value = json.dumps(value, ensure_ascii=False, allow_nan=False)
        return self._texter.text(value)

    def _build(
        self,
        event: str,
        *,
        session: Any = None,
        principal: Any = None,
        tool: Any = None,
        arguments: Any = None,
        outcome: Any = None,
        detail: Any = None,
        operator: Any = None,
        extra: Any = None,
    ) -> tuple[AuditRecord, bytes]:
        """Make the next record (caller holds the lock or is the constructor)."""
        if not isinstance(event, str) or not event or len(event) > MAX_EVENT_CHARS:
            raise ValueError(f"audit event must be a non-empty str of at most {MAX_EVENT_CHARS} chars")
        event = self._texter.text(event, MAX_EVENT_CHARS)
        if extra is not None:
            extra = sanitize(extra, max_string_chars=self._max_chars)
            if not isinstance(extra, dict):
                extra = {"value": extra}
        body: dict[str, Any] = {
            "seq": self._seq + 1,
            "wall_time": _utc_now(),
            "mono_time": time.monotonic(),
            "event": event,
            "session": self._text_field(session),
            "principal": self._text_field(principal),
            "tool": self._text_field(tool),
            "arguments": sanitize(arguments, max_string_chars=self._max_chars),
            "outcome": self._text_field(outcome),
            "detail": self._text_field(detail),
            "operator": self._text_field(operator),
            "extra": extra,
            "prev": self._prev,
        }
        body_json = _canonical(body)
        body["hash"] = _digest(body_json, self._key)
        line = _with_hash(body_json, body["hash"]) + b"\n"
        return AuditRecord(**body), line

    def _write(self, data: bytes, sync: bool = True) -> None:
        assert self._fd is not None
        view = memoryview(data)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
        if sync:
            os.fsync(self._fd)

    def _fsync_written(self) -> None:
        """fsync what was written without it (a group commit by the writer thread)."""
        with self._lock:
            if self._fd is None:
                raise AuditWriteError(f"audit log {str(self._path)!r} is closed")
            try:
                os.fsync(self._fd)
            except OSError as exc:
                self._broken = str(exc)
                raise AuditWriteError(f"cannot fsync audit log {str(self._path)!r}: {exc}") from exc

    def append(
        self,
        event: str,
        *,
        session: str | None = None,
        principal: str | None = None,
        tool: str | None = None,
        arguments: Any = None,
        outcome: str | None = None,
        detail: str | None = None,
        operator: str | None = None,
        extra: Mapping[str, Any] | None = None,
        _sync: bool = True,
    ) -> AuditRecord:
        """Write one record and fsync it; returns the record. Raises AuditWriteError on failure.

        After a write failure the log refuses further appends (the file may now end in a torn
        line; reopening recovers it), so callers fail closed instead of writing past a hole.
        """
        with self._lock:
            if self._fd is None:
                raise AuditWriteError(f"audit log {str(self._path)!r} is closed")
            if self._broken is not None:
                raise AuditWriteError(
                    f"audit log {str(self._path)!r} is unusable after an earlier write failure: {self._broken}"
                )
            record, line = self._build(
                event,
                session=session,
                principal=principal,
                tool=tool,
                arguments=arguments,
                outcome=outcome,
                detail=detail,
                operator=operator,
                extra=extra,
            )
            try:
                self._write(line, sync=_sync)
            except OSError as exc:
                self._broken = str(exc)
                raise AuditWriteError(f"cannot write audit record to {str(self._path)!r}: {exc}") from exc
            self._seq, self._prev = record.seq, record.hash
            return record

    async def append_async(
        self,
        event: str,
        *,
        session: str | None = None,
        principal: str | None = None,
        tool: str | None = None,
        arguments: Any = None,
        outcome: str | None = None,
        detail: str | None = None,
        operator: str | None = None,
        extra: Mapping[str, Any] | None = None,
    ) -> AuditRecord:
        """`append` on the log's own writer thread, so the event loop never waits on disk.

        Records are written in the order of the calls. A record handed to the writer is always
        written — also when the caller is cancelled meanwhile (the event happened; the log must
        say so). A dedicated thread and a plain queue cost far less per record than a generic
        thread pool hop, which matters because every tool call writes one.
        """
        call = functools.partial(
            self.append,
            event,
            session=session,
            principal=principal,
            tool=tool,
            arguments=arguments,
            outcome=outcome,
            detail=detail,
            operator=operator,
            extra=extra,
            _sync=False,  # the writer thread fsyncs each batch before answering any of its callers
        )
        loop = asyncio.get_running_loop()
        future: asyncio.Future[AuditRecord] = loop.create_future()
        self._writer().put((call, loop, future))
        return await asyncio.shield(future)

    def _writer(self) -> queue.SimpleQueue:
        with self._lock:
            if self._queue is None:
                if self._fd is None:
                    raise AuditWriteError(f"audit log {self.path} is closed")
                self._queue = queue.SimpleQueue()
                self._thread = threading.Thread(target=self._drain, args=(self._queue,), name="armwarden-audit", daemon=True)
                self._thread.start()
            return self._queue

    def _drain(self, jobs: queue.SimpleQueue) -> None:
        """Writer thread: take every queued record, write them in order, fsync once, then answer
        their callers — each record is on disk before its call returns, and under load one fsync
        serves many calls."""
        while True:
            job = jobs.get()
            if job is None:
                return
            batch, stopping = [job], False
            while True:
                try:
                    more = jobs.get_nowait()
                except queue.Empty:
                    break
                if more is None:
                    stopping = True
                    break
                batch.append(more)
            outcomes = []
            for call, loop, future in batch:
                try:
                    outcomes.append((loop, future, call(), False))
                except BaseException as exc:  # handed back to the awaiting caller
                    outcomes.append((loop, future, exc, True))
            if any(not failed for *_, failed in outcomes):
                try:
                    self._fsync_written()
                except BaseException as exc:  # nothing of this batch is known to be on disk
                    outcomes = [(loop, future, exc, True) for loop, future, *_ in outcomes]
            for loop, future, outcome, failed in outcomes:
                try:
                    loop.call_soon_threadsafe(_settle, future, outcome, failed)
                except RuntimeError:  # the loop is closed: nobody is waiting any more
                    pass
            if stopping:
                return

    # -- reading ---------------------------------------------------------------------------
    def tail(self, n: int = 20) -> list[dict[str, Any]]:
        """The last ``n`` records (clamped to 1..1000), oldest first."""
        with self._lock:
            if self._fd is None:
                raise AuditWriteError(f"audit log {str(self._path)!r} is closed")
            with os.fdopen(os.dup(self._fd), "rb") as stream:
                lines = _tail_lines(stream, _clamp_tail(n))
        out: list[dict[str, Any]] = []
        for line in lines:
            try:
                obj = _DECODER.decode(line.decode("utf-8"))
            except (UnicodeDecodeError, ValueError, RecursionError):
                continue
            if isinstance(obj, dict):
                out.append(obj)
        return out

    # -- closing ---------------------------------------------------------------------------
    def close(self) -> None:
        """Release the file. Idempotent; writes nothing (a ``shutdown`` record is the caller's).

        Records already handed to the writer thread are written first."""
        with self._lock:
            jobs, thread, self._queue, self._thread = self._queue, self._thread, None, None
        if jobs is not None and thread is not None:
            jobs.put(None)
            if thread is not threading.current_thread():
                thread.join()
        with self._lock:
            fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # closing drops the flock

    def __enter__(self) -> AuditLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._fd is None else f"seq={self._seq}"
        keyed = "hmac" if self._key is not None else "sha256"
        return f"<AuditLog {str(self._path)!r} {keyed} {state}>"


def _last_byte(fd: int, size: int) -> bytes:
    return os.pread(fd, 1, size - 1)


def _settle(future: asyncio.Future, outcome: Any, failed: bool) -> None:
    if future.done():  # the caller went away (cancelled): the record is written regardless
        return
    if failed:
        future.set_exception(outcome)
    else:
        future.set_result(outcome)


def _fsync_dir(directory: Path) -> None:
    try:
        dfd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


# --------------------------------------------------------------------------------------------
# CLI helpers (wired up as `armwarden audit verify|tail`)
# --------------------------------------------------------------------------------------------


def verify_command(path: str | os.PathLike[str], key: bytes | None = None) -> int:
    """Print a one-line verdict for the log at ``path``; 0 if the chain is intact, else 1."""
    try:
        report = verify_file(path, key)
    except (OSError, ConfigurationError) as exc:
        print(f"FAILED: cannot read {os.fspath(path)}: {exc}")
        return 1
    if report.ok:
        note = ""
        if report.recovered_lines:
            listed = ", ".join(str(n) for n in report.recovered_lines)
            note = f" (recovered torn fragment at line {listed})"
        print(f"OK: {report.records} records, chain intact{note}")
        return 0
    hint = ""
    if key is None and report.reason == "hash mismatch" and report.first_bad_line == 1:
        hint = f" (no HMAC key given; set {AUDIT_KEY_ENV} if this log is keyed)"
    print(f"FAILED at line {report.first_bad_line}: {report.reason}{hint}")
    return 1


def tail_command(path: str | os.PathLike[str], n: int = 20) -> int:
    """Print the last ``n`` records of the log as indented JSON; 0 on success, 1 if unreadable."""
    try:
        records = read_tail(path, n)
    except OSError as exc:
        print(f"cannot read {os.fspath(path)}: {exc}", file=sys.stderr)
        return 1
    for record in records:
        print(json.dumps(record, indent=2, ensure_ascii=False, sort_keys=False))
    return 0
