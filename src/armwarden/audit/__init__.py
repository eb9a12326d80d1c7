"""Append-only, hash-chained JSONL audit log: every call, refusal, prompt, answer and e-stop.

See docs/architecture.md, "Where each limit is enforced" (the audit row), for where records are
written. One record per line, written with a single ``write`` and ``fsync``-ed before
`AuditLog.append` returns; records of read-only calls (`AuditLog.append_soon`) are fsync-ed
within a bounded group-commit window instead (see `writer`). Every record carries ``prev`` (the previous record's ``hash``; 64
zeros for the first) and ``hash`` = SHA-256 — or HMAC-SHA256 when a key is configured — over
the canonical JSON of the record without ``hash``::

    json.dumps(record_without_hash, sort_keys=True, separators=(",", ":"),
               ensure_ascii=False).encode("utf-8")

The line itself is the canonical JSON of the full record, so *any* byte edit is detected.

A crash can leave a torn last line; on open the log appends a ``recovery`` record naming the
fragment (``torn_line``, ``torn_bytes``, ``torn_sha256``) and `verify_file` accepts exactly that
fragment (``recovered_lines``). Anything else that does not verify refuses the open.

Limits of the scheme: without an HMAC key anybody with write access can recompute a whole
chain, so only the keyed mode detects forgery; removing whole records from the *end* of the file
is not detectable from the file alone (compare `seq` against an external copy of the tail).

Modules: `sanitise` (bounded, strict-JSON copies of arguments), `chain` (record fields,
canonical JSON, hashing, the key), `verify` (chain verification and tail reading), `writer` (the
writer thread and its durability classes), `entry` (what a caller records, and the record it
becomes), `disk` (opening and locking the file, the disk seam), `log` (the log), `query` (the record filters of `audit tail`) and
`cli` (`armwarden audit verify|tail`).
"""

from __future__ import annotations

from armwarden.audit.chain import (
    AUDIT_KEY_ENV,
    GENESIS_HASH,
    RECORD_FIELDS,
    AuditRecord,
    hmac_key_for_serving,
    hmac_key_from_env,
)
from armwarden.audit.cli import tail_command, verify_command
from armwarden.audit.disk import OS_DISK, Disk
from armwarden.audit.entry import MAX_EVENT_CHARS, AuditEntry
from armwarden.audit.log import DEFAULT_COMMIT_WINDOW_S, AuditLog, AuditWriteError
from armwarden.audit.query import RecordFilter, parse_since
from armwarden.audit.sanitise import sanitize
from armwarden.audit.verify import (
    MAX_TAIL,
    VerifiedPrefix,
    VerifyReport,
    read_tail,
    verify_appended,
    verify_file,
)
from armwarden.audit.writer import MAX_COMMIT_WINDOW_S, Durability

__all__ = [
    "AUDIT_KEY_ENV",
    "DEFAULT_COMMIT_WINDOW_S",
    "GENESIS_HASH",
    "MAX_COMMIT_WINDOW_S",
    "MAX_EVENT_CHARS",
    "MAX_TAIL",
    "OS_DISK",
    "RECORD_FIELDS",
    "AuditEntry",
    "AuditLog",
    "AuditRecord",
    "AuditWriteError",
    "Disk",
    "Durability",
    "RecordFilter",
    "VerifiedPrefix",
    "VerifyReport",
    "hmac_key_for_serving",
    "hmac_key_from_env",
    "parse_since",
    "read_tail",
    "sanitize",
    "tail_command",
    "verify_appended",
    "verify_command",
    "verify_file",
]
