"""`armwarden audit verify|tail`: a one-line verdict on a log, and its last (matching) records as JSON.

`armwarden audit replay` lives in `armwarden.replay` (it needs the planner and the envelope).
"""

from __future__ import annotations

import json
import os
import sys

from armwarden.audit.chain import AUDIT_KEY_ENV
from armwarden.audit.query import RecordFilter
from armwarden.audit.verify import clamp_tail, decode_records, read_tail, verify_file
from armwarden.core.errors import ConfigurationError


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
    if report.reason == "hash mismatch" and report.first_bad_line == 1:
        # the first record's hash is the first use of the key: a mismatch there is most often the key
        unexpanded = "an unexpanded ${...} that a client passed on literally, which is then the key"
        if key is None:
            hint = f" (no HMAC key given; set {AUDIT_KEY_ENV} if this log is keyed: the key, or {unexpanded})"
        else:
            hint = f" (the {AUDIT_KEY_ENV} key may be wrong, or the log's key was {unexpanded})"
    print(f"FAILED at line {report.first_bad_line}: {report.reason}{hint}")
    return 1


def tail_command(path: str | os.PathLike[str], n: int = 20, where: RecordFilter | None = None) -> int:
    """Print the last ``n`` records of the log (with ``where``: the last ``n`` that match it) as
    indented JSON; 0 on success, 1 if unreadable."""
    try:
        if where is None or where.empty:
            records = read_tail(path, n)
        else:
            with open(path, "rb") as stream:
                records = [record for record in decode_records(list(stream)) if where.matches(record)][-clamp_tail(n):]
    except OSError as exc:
        print(f"cannot read {os.fspath(path)}: {exc}", file=sys.stderr)
        return 1
    for record in records:
        text = json.dumps(record, indent=2, ensure_ascii=False, sort_keys=False)
        # a lone surrogate (only a damaged or forged file has one: the writer replaces them) is
        # printed as the JSON escape it was read from, not raised as an encoding error
        print(text.encode("utf-8", "backslashreplace").decode("utf-8"))
    return 0
