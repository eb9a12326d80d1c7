"""Audit log: hash chain, tamper detection, crash recovery, sanitising, concurrency."""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
import os
import stat
import threading
from pathlib import Path

import anyio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armwarden.audit import (
    AUDIT_KEY_ENV,
    GENESIS_HASH,
    RECORD_FIELDS,
    AuditEntry,
    AuditLog,
    AuditRecord,
    AuditWriteError,
    hmac_key_from_env,
    read_tail,
    sanitize,
    tail_command,
    verify_appended,
    verify_command,
    verify_file,
)
from armwarden.core.errors import ConfigurationError

KEY = b"correct horse battery staple"


def write_log(path: Path, n: int, *, key: bytes | None = None) -> list[AuditRecord]:
    with AuditLog(path, hmac_key=key) as log:
        return [
            log.append("tool_call", session="s1", tool="get_robot_state", arguments={"i": i}, outcome="ok")
            for i in range(n)
        ]


def lines_of(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def canonical(obj: dict) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


# --- chain ------------------------------------------------------------------------------------


def test_chain_verifies_after_many_appends(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    records = write_log(path, 500)
    report = verify_file(path)
    assert report.ok and report.records == 500
    assert report.first_bad_line is None and report.reason is None and report.recovered_lines == []
    assert [r.seq for r in records] == list(range(1, 501))
    assert records[0].prev == GENESIS_HASH
    assert all(b.prev == a.hash for a, b in itertools.pairwise(records))


def test_verifying_a_growing_log_again_parses_only_the_appended_records(tmp_path: Path, monkeypatch) -> None:
    from armwarden.audit import verify as verify_module

    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        for i in range(50):
            log.append("tool_call", tool="get_robot_state", arguments={"i": i}, outcome="ok")
        first, verified = verify_appended(path)
        checked: list[int] = []
        original = verify_module._check_line
        monkeypatch.setattr(verify_module, "_check_line", lambda *a: checked.append(1) or original(*a))
        for i in range(5):
            log.append("tool_call", tool="get_robot_state", arguments={"i": 50 + i}, outcome="ok")
        again, _ = verify_appended(path, previous=verified)
    assert len(checked) == 5  # the five new records, not the fifty verified before
    assert first.ok and first.records == 50
    assert again == verify_file(path) and again.records == 55


def test_an_edit_before_where_the_last_verification_ended_is_still_found(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 5)
    _, verified = verify_appended(path)
    data = bytearray(path.read_bytes())
    data[len(lines_of(path)[0]) + 10] ^= 0x01  # one byte of line 2
    path.write_bytes(bytes(data))
    report, resume = verify_appended(path, previous=verified)
    assert not report.ok and report.first_bad_line == 2 and resume is None
    assert report == verify_file(path)


def test_a_bad_appended_record_is_named_by_its_line(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 3)
    _, verified = verify_appended(path)
    with path.open("ab") as stream:
        stream.write(b'{"not": "a record"}\n')
    report, resume = verify_appended(path, previous=verified)
    assert not report.ok and report.first_bad_line == 4 and resume is None
    assert report == verify_file(path)


def test_each_line_is_the_canonical_json_of_a_record_with_every_field(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        rec = log.append(
            "approval_answer",
            session="sess",
            principal="alice",
            tool="execute_plan",
            arguments={"plan_id": "p1"},
            outcome="ok",
            detail="approved",
            operator="bob",
            extra={"code": "AB12"},
        )
    (line,) = lines_of(path)
    obj = json.loads(line)
    assert tuple(sorted(obj)) == tuple(sorted(RECORD_FIELDS))
    assert line == canonical(obj) + b"\n"
    assert obj == rec.to_dict()
    body = {k: v for k, v in obj.items() if k != "hash"}
    assert obj["hash"] == hashlib.sha256(canonical(body)).hexdigest()
    assert obj["wall_time"].endswith("Z") and "." in obj["wall_time"]
    assert isinstance(obj["mono_time"], float)


def test_one_byte_edit_anywhere_in_a_record_fails_naming_that_line(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 5)
    original = lines_of(path)
    target = original[2]  # line 3
    start = sum(len(line) for line in original[:2])
    data = b"".join(original)
    for offset in range(len(target) - 1):  # every byte of the record, newline excluded
        pos = start + offset
        for replacement in {data[pos] ^ 0x01, data[pos] ^ 0x20}:
            path.write_bytes(data[:pos] + bytes([replacement]) + data[pos + 1 :])
            report = verify_file(path)
            assert not report.ok, (offset, replacement)
            assert report.first_bad_line == 3, (offset, replacement, report)


def test_deleting_a_middle_line_fails(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 6)
    lines = lines_of(path)
    path.write_bytes(b"".join(lines[:3] + lines[4:]))
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 4
    assert report.reason is not None and "sequence" in report.reason


def test_reordering_two_lines_fails(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 6)
    lines = lines_of(path)
    lines[2], lines[3] = lines[3], lines[2]
    path.write_bytes(b"".join(lines))
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 3


def forged_after(prev_line: bytes, *, key: bytes | None) -> bytes:
    """A well-formed record that continues the chain after prev_line, hashed with SHA-256."""
    prev = json.loads(prev_line)
    body = dict(prev, seq=prev["seq"] + 1, event="approval_answer", outcome="ok", detail="forged", prev=prev["hash"])
    del body["hash"]
    body["hash"] = hashlib.sha256(canonical(body)).hexdigest()
    return canonical(body) + b"\n"


def test_inserted_forged_line_with_recomputed_sha256_fails_under_hmac(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 4, key=KEY)
    lines = lines_of(path)
    # appended at the end: seq and prev are perfect, only the keyed hash can tell
    path.write_bytes(b"".join(lines) + forged_after(lines[-1], key=KEY))
    report = verify_file(path, KEY)
    assert not report.ok and report.first_bad_line == 5 and report.reason == "hash mismatch"
    # inserted in the middle
    path.write_bytes(b"".join(lines[:2] + [forged_after(lines[1], key=KEY)] + lines[2:]))
    report = verify_file(path, KEY)
    assert not report.ok and report.first_bad_line == 3


def test_inserted_forged_line_in_the_middle_of_an_unkeyed_log_fails(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 4)
    lines = lines_of(path)
    path.write_bytes(b"".join(lines[:2] + [forged_after(lines[1], key=None)] + lines[2:]))
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 4  # the forged line itself chains; the next cannot


def test_truncating_the_file_mid_line_fails(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 5)
    data = path.read_bytes()
    lines = lines_of(path)
    cut = sum(len(line) for line in lines[:3]) + len(lines[3]) // 2
    path.write_bytes(data[:cut])
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 4 and report.reason == "torn last line"


def test_shortening_a_middle_line_fails(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 5)
    lines = lines_of(path)
    lines[1] = lines[1][: len(lines[1]) // 2] + b"\n"
    path.write_bytes(b"".join(lines))
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 2


# --- restart and crash recovery -----------------------------------------------------------------


def test_restart_continues_the_chain(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    first = write_log(path, 3)
    with AuditLog(path) as log:
        assert log.last_seq == 3 and log.last_hash == first[-1].hash
        rec = log.append("startup")
    assert rec.seq == 4 and rec.prev == first[-1].hash
    assert verify_file(path).ok and verify_file(path).records == 4


def test_torn_last_line_is_reported_then_recovered_on_reopen(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    good = write_log(path, 3)
    fragment = b'{"arguments":{"i":3},"detail":null,"ev'  # crash mid-write
    with open(path, "ab") as f:
        f.write(fragment)
    report = verify_file(path)
    assert not report.ok and report.reason == "torn last line" and report.first_bad_line == 4
    assert report.records == 3
    size_before = path.stat().st_size

    with AuditLog(path) as log:
        recovery = log.recovery_record
        assert recovery is not None and recovery.event == "recovery"
        assert recovery.seq == 4 and recovery.prev == good[-1].hash
        assert recovery.extra is not None
        assert recovery.extra["torn_line"] == 4 and recovery.extra["torn_bytes"] == len(fragment)
        after = log.append("startup")
    assert after.seq == 5 and after.prev == recovery.hash

    data = path.read_bytes()
    assert data[:size_before].endswith(fragment)  # history untouched, only appended to
    assert data[size_before : size_before + 1] == b"\n"
    report = verify_file(path)
    assert report.ok and report.records == 5 and report.recovered_lines == [4]
    with AuditLog(path) as log:  # a recovered log reopens cleanly, without a second recovery
        assert log.recovery_record is None and log.last_seq == 5


def test_a_recovery_cut_short_is_recovered_with_its_fragment_on_the_next_open(tmp_path: Path) -> None:
    """A full disk or a power cut can tear a write, and then tear the recovery record written for
    it at the next start: the log must still open, and claim both torn lines as one tail."""
    path = tmp_path / "audit.jsonl"
    good = write_log(path, 3)
    torn_record = b'{"arguments":{"i":3},"detail":null,"ev'
    torn_recovery = b'{"event":"recovery","extra":{"torn_by'  # the first recovery, cut short
    with open(path, "ab") as f:
        f.write(torn_record + b"\n" + torn_recovery)
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 4 and report.records == 3

    with AuditLog(path) as log:
        recovery = log.recovery_record
        assert recovery is not None and recovery.seq == 4 and recovery.prev == good[-1].hash
        assert recovery.extra is not None and recovery.extra["torn_line"] == 4
        assert recovery.extra["torn_bytes"] == len(torn_record) + 1 + len(torn_recovery)
        assert recovery.detail is not None and "lines 4-5" in recovery.detail
        log.append("startup")
    report = verify_file(path)
    assert report.ok and report.records == 5 and report.recovered_lines == [4, 5]


def test_a_recovery_record_claiming_only_part_of_the_torn_lines_before_it_fails(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 2)
    with open(path, "ab") as f:
        f.write(b'{"seq":3,"ev\n{"seq":3,"detail"')
    AuditLog(path).close()  # recovers lines 3-4 as one tail
    assert verify_file(path).recovered_lines == [3, 4]
    lines = lines_of(path)
    del lines[2]  # drop the first fragment: the claim no longer matches what precedes it
    path.write_bytes(b"".join(lines))
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 3


def test_complete_record_missing_only_its_newline_is_treated_as_torn(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 3)
    path.write_bytes(path.read_bytes()[:-1])  # the fsync never confirmed this record
    assert verify_file(path).reason == "torn last line"
    with AuditLog(path) as log:
        recovery = log.recovery_record
        assert recovery is not None and recovery.extra is not None
        assert recovery.seq == 3 and recovery.extra["torn_line"] == 3
    report = verify_file(path)
    assert report.ok and report.recovered_lines == [3] and report.records == 3


def test_recovered_fragment_cannot_be_edited_afterwards(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 2)
    with open(path, "ab") as f:
        f.write(b'{"seq":3,"ev')
    AuditLog(path).close()
    assert verify_file(path).ok
    path.write_bytes(path.read_bytes().replace(b'{"seq":3,"ev', b'{"seq":9,"ev'))
    report = verify_file(path)
    assert not report.ok and report.first_bad_line == 3


def test_opening_a_log_with_a_corrupt_middle_line_refuses(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 5)
    lines = lines_of(path)
    lines[2] = b"garbage\n"
    path.write_bytes(b"".join(lines))
    before = path.read_bytes()
    with pytest.raises(ConfigurationError, match=r"line 3"):
        AuditLog(path)
    assert path.read_bytes() == before  # nothing written on top


def test_opening_a_log_whose_last_record_was_tampered_refuses(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 3)
    path.write_bytes(path.read_bytes().replace(b'"i":2', b'"i":7'))  # valid JSON, broken hash
    with pytest.raises(ConfigurationError, match=r"line 3: hash mismatch"):
        AuditLog(path)


def test_missing_parent_directory_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="does not exist"):
        AuditLog(tmp_path / "nope" / "audit.jsonl")
    assert not (tmp_path / "nope").exists()


def test_second_writer_on_the_same_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path):
        with pytest.raises(ConfigurationError, match="already open"):
            AuditLog(path)
    AuditLog(path).close()  # released on close


def test_new_log_file_is_private_and_close_is_idempotent_and_silent(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    log = AuditLog(path)
    log.append("startup")
    size = path.stat().st_size
    log.close()
    log.close()
    assert path.stat().st_size == size
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    with pytest.raises(AuditWriteError, match="closed"):
        log.append("tool_call")


@pytest.fixture(scope="module")
def developer_key_in_the_environment():
    """The developer's shell exported a key before the test run started."""
    previous = os.environ.get(AUDIT_KEY_ENV)
    os.environ[AUDIT_KEY_ENV] = "a developer's own key"
    yield
    if previous is None:
        os.environ.pop(AUDIT_KEY_ENV, None)
    else:
        os.environ[AUDIT_KEY_ENV] = previous


def test_a_developers_audit_key_does_not_reach_a_test(developer_key_in_the_environment: None) -> None:
    assert AUDIT_KEY_ENV not in os.environ
    assert hmac_key_from_env() is None


def test_a_test_may_set_the_audit_key_itself(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(AUDIT_KEY_ENV, "test key")
    assert hmac_key_from_env() == b"test key"


def test_event_must_be_a_short_non_empty_string(tmp_path: Path) -> None:
    with AuditLog(tmp_path / "audit.jsonl") as log:
        for bad in ("", "x" * 65, None, 3):
            with pytest.raises(ValueError):
                log.append(bad)  # type: ignore[arg-type]
        assert log.append("x" * 64).seq == 1


# --- entries ------------------------------------------------------------------------------------


def test_append_takes_an_audit_entry(tmp_path: Path) -> None:
    entry = AuditEntry("tool_call", session="s1", tool="estop", arguments={"reason": "x"}, outcome="ok")
    with AuditLog(tmp_path / "audit.jsonl") as log:
        record = log.append(entry)
    assert (record.event, record.session, record.tool, record.arguments, record.outcome) == (
        "tool_call", "s1", "estop", {"reason": "x"}, "ok"
    )


def test_an_entry_and_the_same_keywords_write_the_same_fields(tmp_path: Path) -> None:
    fields = {"principal": "alice", "detail": "d", "operator": "bob", "extra": {"k": 1}}
    with AuditLog(tmp_path / "audit.jsonl") as log:
        by_entry = log.append(AuditEntry("refusal", **fields)).to_dict()
        by_keywords = log.append("refusal", **fields).to_dict()
    changing = {"seq", "wall_time", "mono_time", "prev", "hash"}
    assert {k: v for k, v in by_entry.items() if k not in changing} == {
        k: v for k, v in by_keywords.items() if k not in changing
    }


def test_an_entry_with_extra_keywords_is_refused(tmp_path: Path) -> None:
    with AuditLog(tmp_path / "audit.jsonl") as log:
        with pytest.raises(TypeError, match="not both"):
            log.append(AuditEntry("tool_call"), tool="estop")
        assert log.last_seq == 0


def test_an_unknown_keyword_is_refused(tmp_path: Path) -> None:
    with AuditLog(tmp_path / "audit.jsonl") as log:
        with pytest.raises(TypeError):
            log.append("tool_call", toll="estop")
        assert log.last_seq == 0


@pytest.mark.anyio
async def test_append_async_takes_an_audit_entry(tmp_path: Path) -> None:
    with AuditLog(tmp_path / "audit.jsonl") as log:
        record = await log.append_async(AuditEntry("shutdown", outcome="ok", detail="bye"))
    assert (record.seq, record.event, record.outcome, record.detail) == (1, "shutdown", "ok", "bye")
    assert verify_file(tmp_path / "audit.jsonl").ok


# --- HMAC ---------------------------------------------------------------------------------------


def test_hmac_log_verifies_only_with_the_right_key(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 3, key=KEY)
    assert verify_file(path, KEY).ok
    no_key = verify_file(path)
    assert not no_key.ok and no_key.first_bad_line == 1 and no_key.reason == "hash mismatch"
    wrong = verify_file(path, b"wrong key")
    assert not wrong.ok and wrong.first_bad_line == 1
    with pytest.raises(ConfigurationError, match="line 1"):
        AuditLog(path, hmac_key=b"wrong key")
    with AuditLog(path, hmac_key=KEY) as log:
        assert log.append("startup").seq == 4


def test_hmac_key_from_env() -> None:
    assert hmac_key_from_env({"ARMWARDEN_AUDIT_KEY": "sécret"}) == "sécret".encode()
    assert hmac_key_from_env({"ARMWARDEN_AUDIT_KEY": ""}) is None
    assert hmac_key_from_env({}) is None


# --- sanitising ---------------------------------------------------------------------------------


class Hostile:
    def __repr__(self) -> str:
        raise RuntimeError("no repr for you")

    def __eq__(self, other: object) -> bool:
        raise RuntimeError("no eq")

    __hash__ = object.__hash__


def nested(depth: int) -> list:
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.integers(min_value=2**200, max_value=2**4000),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(),
    st.just("\ud800 lone surrogate"),
    st.integers(min_value=0, max_value=200_000).map(lambda n: "x" * n),
    st.binary(),
    st.binary().map(bytearray),
    st.builds(Hostile),
    st.builds(object),
    st.integers(min_value=0, max_value=300).map(nested),
)
keys = st.one_of(st.text(), st.integers(), st.floats(), st.none(), st.booleans(), st.builds(Hostile))
values = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=8),
        st.lists(children, max_size=8).map(tuple),
        st.dictionaries(keys, children, max_size=8),
        st.fixed_dictionaries({"type": st.just("image"), "data": st.text(), "mimeType": st.just("image/png")}),
    ),
    max_leaves=40,
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(values)
def test_sanitize_never_raises_and_returns_strict_json(value: object) -> None:
    out = sanitize(value)
    text = json.dumps(out, allow_nan=False, ensure_ascii=False, sort_keys=True)
    text.encode("utf-8")  # no lone surrogates survive
    assert len(text) < 2_000_000


def test_sanitize_handles_cycles_and_huge_containers() -> None:
    loop: list = []
    loop.append(loop)
    json.dumps(sanitize(loop), allow_nan=False)
    big = sanitize(list(range(10_000)))
    assert len(big) == 201 and big[-1] == "…[9800 more items]"
    wide = sanitize({str(i): i for i in range(1000)})
    assert len(wide) == 201 and "…" in wide
    assert "…[max depth reached]" in json.dumps(sanitize(nested(50)), ensure_ascii=False)


def test_non_finite_floats_become_strings() -> None:
    assert sanitize([math.nan, math.inf, -math.inf, 1.5]) == ["nan", "inf", "-inf", 1.5]


def test_image_bytes_are_redacted(tmp_path: Path) -> None:
    b64 = "iVBORw0KGgo" * 1000
    args = {
        "content": [{"type": "image", "data": b64, "mimeType": "image/png"}, {"type": "text", "text": "hi"}],
        "png": b"\x89PNG" + b"\0" * 96,
        "image": b64,
        "jpeg": "A" * 200,
        "camera": "wrist",
        "raw": bytearray(10),
        "uri": "data:image/png;base64," + b64,
    }
    out = sanitize(args)
    assert out["content"][0]["data"] == f"<redacted {len(b64)} bytes>"
    assert out["content"][1] == {"type": "text", "text": "hi"}
    assert out["png"] == "<redacted 100 bytes>"
    assert out["image"].startswith("<redacted") and out["jpeg"].startswith("<redacted")
    assert out["raw"] == "<redacted 10 bytes>" and out["uri"].startswith("<redacted")
    assert out["camera"] == "wrist"
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        log.append("tool_call", tool="camera_snapshot", arguments=args)
    assert b"iVBORw0KGgo" not in path.read_bytes()


def test_long_strings_are_truncated_with_a_marker(tmp_path: Path) -> None:
    assert sanitize("a" * 1234) == "a" * 500 + "…[truncated 734 chars]"
    assert sanitize("short") == "short"
    with AuditLog(tmp_path / "audit.jsonl", max_string_chars=100) as log:
        rec = log.append("refusal", detail="d" * 1000, arguments={"note": "n" * 1000})
    assert rec.detail == "d" * 100 + "…[truncated 900 chars]"
    assert rec.arguments["note"].endswith("…[truncated 900 chars]")


# --- concurrency and async ----------------------------------------------------------------------


@pytest.mark.anyio
async def test_append_async_writes_in_call_order_under_anyio(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        first = await log.append_async("startup", detail="async")
        results: list[AuditRecord] = [first]
        async with anyio.create_task_group() as tg:
            for i in range(20):
                async def one(i: int = i) -> None:
                    results.append(await log.append_async("tool_call", arguments={"i": i}))

                tg.start_soon(one)
    assert results[0].seq == 1 and len(results) == 21
    written = [json.loads(line) for line in lines_of(path)]
    assert [r["arguments"]["i"] for r in written[1:]] == list(range(20))  # FIFO: call order
    assert verify_file(path).ok and verify_file(path).records == 21


def test_concurrent_appends_from_eight_threads_keep_the_chain_valid(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    per_thread = 100
    with AuditLog(path) as log:
        barrier = threading.Barrier(8)
        errors: list[BaseException] = []

        def worker(t: int) -> None:
            try:
                barrier.wait()
                for i in range(per_thread):
                    log.append("tool_call", session=f"t{t}", arguments={"i": i})
            except BaseException as exc:  # pragma: no cover - reported below
                errors.append(exc)

        threads = [threading.Thread(target=worker, args=(t,)) for t in range(8)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    assert not errors
    report = verify_file(path)
    assert report.ok and report.records == 8 * per_thread
    written = [json.loads(line) for line in lines_of(path)]
    for t in range(8):  # each thread's own records stay in its call order
        assert [r["arguments"]["i"] for r in written if r["session"] == f"t{t}"] == list(range(per_thread))


# --- tail and CLI helpers -----------------------------------------------------------------------


def test_tail_returns_the_last_records_and_clamps_n(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        for i in range(30):
            log.append("tool_call", arguments={"i": i})
        assert [r["seq"] for r in log.tail(3)] == [28, 29, 30]
        assert [r["seq"] for r in log.tail(0)] == [30]
        assert len(log.tail(10**9)) == 30
    assert [r["seq"] for r in read_tail(path, 2)] == [29, 30]
    with open(path, "ab") as f:
        f.write(b'{"torn')
    assert [r["seq"] for r in read_tail(path, 2)] == [30]  # fragments are skipped


def test_verify_command_prints_one_line_and_returns_status(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 4, key=KEY)
    assert verify_command(path, KEY) == 0
    assert capsys.readouterr().out == "OK: 4 records, chain intact\n"
    assert verify_command(path, None) == 1
    out = capsys.readouterr().out
    assert out.startswith("FAILED at line 1: hash mismatch") and out.count("\n") == 1
    assert verify_command(tmp_path / "missing.jsonl", None) == 1
    assert capsys.readouterr().out.startswith("FAILED")


def test_tail_command_prints_pretty_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "audit.jsonl"
    write_log(path, 5)
    assert tail_command(path, 2) == 0
    out = capsys.readouterr().out
    assert '"seq": 4' in out and '"seq": 5' in out and '"seq": 3' not in out
    assert tail_command(tmp_path / "missing.jsonl", 2) == 1


def test_sanitized_log_survives_hostile_arguments(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        log.append(
            "tool_call",
            tool="plan_to_joints",
            arguments={"q": [math.nan, math.inf], "obj": Hostile(), Hostile(): 1, "s": "\ud800"},
            extra=[1, 2],  # type: ignore[arg-type]
            session=123,  # type: ignore[arg-type]
        )
    assert verify_file(path).ok
    (rec,) = read_tail(path, 1)
    assert rec["arguments"]["q"] == ["nan", "inf"]
    assert rec["extra"] == {"value": [1, 2]} and rec["session"] == "123"
    assert os.path.getsize(path) < 10_000


def test_a_failed_write_makes_the_log_refuse_further_appends(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "audit.jsonl"
    log = AuditLog(path)
    log.append("startup")

    def no_space(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", no_space)
    with pytest.raises(AuditWriteError, match="No space"):
        log.append("tool_call")
    monkeypatch.undo()
    with pytest.raises(AuditWriteError, match="unusable"):  # fail closed: never write past a hole
        log.append("tool_call")
    log.close()


@pytest.mark.anyio
async def test_concurrent_async_appends_share_fsyncs_and_keep_the_chain(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"

    with AuditLog(path) as log:
        async with anyio.create_task_group() as group:
            for i in range(60):
                group.start_soon(functools.partial(log.append_async, "tool_call", arguments={"i": i}))
    report = verify_file(path)
    assert report.ok and report.records == 60


@pytest.mark.anyio
async def test_a_failed_group_fsync_fails_every_caller_of_the_batch(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"
    errors: list[BaseException] = []

    with AuditLog(path) as log:
        def broken_fsync(fd: int) -> None:
            raise OSError(5, "simulated I/O error")

        monkeypatch.setattr("armwarden.audit.log.os.fsync", broken_fsync)

        async def one(i: int) -> None:
            try:
                await log.append_async("tool_call", arguments={"i": i})
            except AuditWriteError as exc:
                errors.append(exc)

        async with anyio.create_task_group() as group:
            for i in range(5):
                group.start_soon(one, i)
        monkeypatch.undo()
    assert len(errors) == 5
