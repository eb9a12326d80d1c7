"""Reading a log back: verifying the chain line by line, and reading its last records.

`scan` is shared by `verify_file` and by `AuditLog` when it opens a file (to continue the chain
or to recover a torn last line).
"""

from __future__ import annotations

import hashlib
import hmac as _hmac
import os
from dataclasses import dataclass, field
from typing import IO, Any

from armwarden.audit.chain import (
    DECODER,
    FIELD_SET,
    GENESIS_HASH,
    RECOVERY_MARK,
    canonical_json,
    check_key,
    digest,
    with_hash,
)

MAX_TAIL = 1000

@dataclass(frozen=True)
class VerifyReport:
    ok: bool
    records: int
    first_bad_line: int | None
    reason: str | None
    recovered_lines: list[int] = field(default_factory=list)


@dataclass
class Scan:
    """Result of walking a log: the report plus what a writer needs to continue the chain."""

    report: VerifyReport
    last_seq: int
    last_hash: str
    bad_is_last: bool = False  # from the first bad line on, the file holds nothing but torn writes
    bad_parses: bool = False  # the first bad line is a JSON object (so not a torn write)
    bad_bytes: bytes = b""  # its content without the newline (a torn tail: all of it, lines joined)
    lines: int = 0  # lines read, fragments included (a clean scan: every line of the file)


@dataclass(frozen=True)
class VerifiedPrefix:
    """Where a clean verification of a log ended (at a line boundary), so that the next one
    (`verify_appended`) parses only what was appended since, once the prefix still hashes the same."""

    size: int  # bytes verified
    sha256: str  # of those bytes
    scan: Scan  # the clean scan that covered them


def _check_line(
    content: bytes, expected_seq: int, prev_hash: str, key: bytes | None
) -> tuple[dict[str, Any] | None, str | None, bool]:
    """Validate one newline-stripped line. Returns (record, failure reason, parsed as object)."""
    try:
        obj = DECODER.decode(content.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None, "invalid JSON", False
    if not isinstance(obj, dict):
        return None, "not a JSON object", False
    keys = set(obj)
    if keys != FIELD_SET:
        missing = sorted(FIELD_SET - keys)
        unknown = sorted(keys - FIELD_SET)
        what = f"missing field(s) {missing}" if missing else f"unknown field(s) {unknown}"
        return None, what, True
    claimed = obj["hash"]
    body = {k: v for k, v in obj.items() if k != "hash"}
    try:
        body_json = canonical_json(body)
    except (ValueError, TypeError, UnicodeEncodeError):
        return None, "hash mismatch", True
    expected = digest(body_json, key)
    if not isinstance(claimed, str) or not _hmac.compare_digest(claimed, expected):
        return None, "hash mismatch", True
    if content != with_hash(body_json, expected):
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
    if RECOVERY_MARK not in next_content:
        return None
    try:
        obj = DECODER.decode(next_content.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None
    if not isinstance(obj, dict) or obj.get("event") != "recovery":
        return None
    extra = obj.get("extra")
    if isinstance(extra, dict) and type(extra.get("torn_line")) is int and extra["torn_line"] == lineno:
        return extra
    return None


def scan(stream: IO[bytes], key: bytes | None, resume: Scan | None = None) -> Scan:
    """Verify the lines from the stream's position to its end; `resume`: the clean scan of the
    bytes before that position, whose chain these lines must continue."""
    done = resume if resume is not None else Scan(VerifyReport(True, 0, None, None), 0, GENESIS_HASH)
    lines = enumerate(stream, start=done.lines + 1)  # binary iteration splits on b"\n" only
    records = done.report.records
    last_seq, last_hash = done.last_seq, done.last_hash
    recovered: list[int] = list(done.report.recovered_lines)
    lineno = done.lines

    def fail(lineno: int, reason: str, is_last: bool, parses: bool, content: bytes) -> Scan:
        return Scan(
            VerifyReport(False, records, lineno, reason, list(recovered)),
            last_seq,
            last_hash,
            bad_is_last=is_last,
            bad_parses=parses,
            bad_bytes=content,
        )

    # consecutive lines that are not records at all (torn writes): a recovery record right after
    # them claims them as one fragment (their bytes joined by newlines), or they end the file (a
    # torn tail a writer recovers); anything else after them fails at the first of them. More than
    # one only when a recovery itself was cut short (a full disk, a power cut at start-up).
    pending: list[tuple[int, bytes, str]] = []  # (line, content, why it is not a record)
    cur = next(lines, None)
    while cur is not None:
        nxt = next(lines, None)
        lineno, raw = cur
        terminated = raw.endswith(b"\n")
        content = raw[:-1] if terminated else raw
        first = pending[0][0] if pending else lineno
        claim = _fragment_claim(nxt[1].rstrip(b"\n"), first) if nxt is not None else None
        if claim is not None:
            joined = _joined(pending, content)
            if claim.get("torn_bytes") != len(joined) or claim.get(
                "torn_sha256"
            ) != hashlib.sha256(joined).hexdigest():
                return fail(first, "fragment does not match its recovery record", False, False, joined)
            recovered.extend(range(first, lineno + 1))
            pending = []
            cur = nxt
            continue
        if not terminated:  # only the last line can lack its newline
            return fail(first, pending[0][2] if pending else "torn last line", True, False, _joined(pending, content))
        obj, reason, parses = _check_line(content, last_seq + 1, last_hash, key)
        if reason is not None and not parses:
            pending.append((lineno, content, reason))  # a fragment: claimed by what follows, or a torn tail
            cur = nxt
            continue
        if pending:  # a record (good or bad) after fragments nothing claimed
            return fail(first, pending[0][2], False, False, pending[0][1])
        if reason is not None:
            return fail(lineno, reason, nxt is None, parses, content)
        assert obj is not None
        records += 1
        last_seq, last_hash = obj["seq"], obj["hash"]
        cur = nxt
    if pending:  # the file ends in fragments only: a torn tail
        return fail(pending[0][0], pending[0][2], True, False, _joined(pending[:-1], pending[-1][1]))
    return Scan(VerifyReport(True, records, None, None, recovered), last_seq, last_hash, lines=lineno)


def _joined(fragments: list[tuple[int, bytes, str]], last: bytes) -> bytes:
    """The bytes of consecutive torn lines as one fragment: their contents joined by newlines."""
    return b"\n".join([*(content for _, content, _ in fragments), last])


def verify_file(path: str | os.PathLike[str], hmac_key: bytes | None = None) -> VerifyReport:
    """Check every line of the log at ``path``: parse, seq +1, prev link, hash, canonical form.

    A torn last line is reported (``reason == "torn last line"``); a fragment that a following
    ``recovery`` record names exactly (line number, byte length, SHA-256) is accepted and listed
    in ``recovered_lines``. Raises OSError if the file cannot be read.
    """
    key = check_key(hmac_key)
    with open(path, "rb") as stream:
        return scan(stream, key).report


def verify_appended(path: str | os.PathLike[str], hmac_key: bytes | None = None,
                    previous: VerifiedPrefix | None = None) -> tuple[VerifyReport, VerifiedPrefix | None]:
    """`verify_file`, for a reader that verifies the same growing log again and again (the
    console): when the file still starts with exactly the bytes `previous` verified (one SHA-256
    over them, far cheaper than parsing and hashing every record again), only the lines appended
    since are parsed; any change to those bytes means a full verification. Returns the report
    (the same as `verify_file`'s) and, when it is clean, where the next call may resume."""
    key = check_key(hmac_key)
    with open(path, "rb") as stream:
        hasher = hashlib.sha256()
        resume = None
        if previous is not None and _starts_with(stream, previous, hasher):
            resume = previous.scan
        else:
            stream.seek(0)
            hasher = hashlib.sha256()
        start = stream.tell()
        scanned = scan(stream, key, resume)
        if not scanned.report.ok:
            return scanned.report, None
        end = stream.tell()
        stream.seek(start)
        _hash_range(stream, end - start, hasher)
    return scanned.report, VerifiedPrefix(end, hasher.hexdigest(), scanned)


def _starts_with(stream: IO[bytes], previous: VerifiedPrefix, hasher: Any) -> bool:
    """Whether the stream's first `previous.size` bytes hash to `previous.sha256` (fed into
    `hasher`, the stream left after them)."""
    return _hash_range(stream, previous.size, hasher) == previous.size and hasher.hexdigest() == previous.sha256


def _hash_range(stream: IO[bytes], size: int, hasher: Any, block: int = 1 << 20) -> int:
    """Feed the next `size` bytes of the stream to `hasher`; how many there were."""
    fed = 0
    while fed < size:
        chunk = stream.read(min(block, size - fed))
        if not chunk:
            break
        hasher.update(chunk)
        fed += len(chunk)
    return fed


# --------------------------------------------------------------------------------------------
# Tail
# --------------------------------------------------------------------------------------------


def clamp_tail(n: Any) -> int:
    try:
        n = int(n)
    except (TypeError, ValueError):
        n = 1
    return min(max(n, 1), MAX_TAIL)


def tail_lines(stream: IO[bytes], n: int, block: int = 65536) -> list[bytes]:
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


def decode_records(lines: list[bytes]) -> list[dict[str, Any]]:
    """The lines that parse as JSON objects, in order; anything else (a torn fragment) is skipped."""
    out: list[dict[str, Any]] = []
    for line in lines:
        try:
            obj = DECODER.decode(line.decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError):
            continue
        if isinstance(obj, dict):
            out.append(obj)
    return out


def read_tail(path: str | os.PathLike[str], n: int = 20) -> list[dict[str, Any]]:
    """The last ``n`` (clamped to 1..1000) parseable records of the log at ``path``, oldest first.

    Lines that are not JSON objects (a torn fragment) are skipped, not returned.
    """
    with open(path, "rb") as stream:
        return decode_records(tail_lines(stream, clamp_tail(n)))
