"""The `AuditLog` writer: one fsync-ed line per record, a writer thread for the event loop.

Crash handling. A crash can leave a torn last line (no trailing newline, or not JSON). On open
the log never rewrites history: it terminates the fragment with a newline and appends a
``recovery`` record, chained from the last good record, whose ``extra`` names the fragment
(``torn_line``, ``torn_bytes``, ``torn_sha256``). Anything else that does not verify makes the
open fail with `ConfigurationError` naming the first bad line: the operator must move the file
aside.

The file itself (opening, locking, the disk seam) is `disk`'s; what a record holds, `entry`'s.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import functools
import hashlib
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armwarden.audit.chain import GENESIS_HASH, AuditRecord, check_key
from armwarden.audit.disk import OS_DISK, Disk, last_byte, open_log_file
from armwarden.audit.entry import AuditEntry, RecordMaker, entry_of
from armwarden.audit.verify import clamp_tail, decode_records, tail_lines
from armwarden.audit.writer import MAX_COMMIT_WINDOW_S, Durability, Job, Writer
from armwarden.core.errors import ArmWardenError, ConfigurationError

#: how long a read-only call's record may wait to be written and fsync-ed [s] (writer.py)
DEFAULT_COMMIT_WINDOW_S = 0.02


class AuditWriteError(ArmWardenError):
    """A record could not be made durable (log closed, disk error). Callers must fail closed."""


class AuditLog:
    """The daemon's audit log. Thread-safe; one writer process per file (advisory lock).

    ``append`` returns only after the record is written and fsync-ed. Use ``append_async`` from
    the event loop: it runs ``append`` in a worker thread (FIFO per log and event loop), so the
    loop never waits for the disk. ``append_soon`` is for records of read-only calls: nobody
    waits, and the record is fsync-ed within ``commit_window_s`` (see `writer`).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        hmac_key: bytes | None = None,
        max_string_chars: int = 500,
        commit_window_s: float = DEFAULT_COMMIT_WINDOW_S,
        disk: Disk = OS_DISK,
    ) -> None:
        self._path = Path(path)
        self._disk = disk
        self._key = check_key(hmac_key)
        if isinstance(max_string_chars, bool) or not isinstance(max_string_chars, int) or not (
            16 <= max_string_chars <= 1_000_000
        ):
            raise ConfigurationError(
                f"audit max_string_chars must be an int in 16..1000000, got {max_string_chars!r}"
            )
        self._records = RecordMaker(self._key, max_string_chars)
        self._lock = threading.Lock()  # the file, the chain's head, the broken flag (held while a record is built)
        # the writer thread and the closing flag: never held while a record is built, so handing a
        # record over never waits for the writer thread's work (a lock convoy under the GIL)
        self._handover_lock = threading.Lock()
        if isinstance(commit_window_s, bool) or not isinstance(commit_window_s, (int, float)) or not (
            0.0 <= commit_window_s <= MAX_COMMIT_WINDOW_S
        ):
            raise ConfigurationError(
                f"audit commit_window_s must be a number in 0..{MAX_COMMIT_WINDOW_S:g} s, got {commit_window_s!r}"
            )
        self._window_s = float(commit_window_s)
        self._writer_thread: Writer | None = None  # started on first use
        self._on_durable: Callable[[str, float], None] | None = None  # `observe_writes`
        self._closing = False  # set by close(): no new writer thread, no new record
        self._fd: int | None = None
        self._broken: str | None = None
        self._seq = 0
        self._prev = GENESIS_HASH
        self._recovery: AuditRecord | None = None
        self._open()

    # -- opening ---------------------------------------------------------------------------
    def _open(self) -> None:
        fd, scanned = open_log_file(self._path, self._key)
        try:
            self._fd = fd
            self._seq, self._prev = scanned.last_seq, scanned.last_hash
            report = scanned.report
            if not report.ok:
                assert report.first_bad_line is not None
                torn = scanned.bad_is_last and (report.reason == "torn last line" or not scanned.bad_parses)
                if not torn:
                    raise ConfigurationError(
                        f"audit log {str(self._path)!r} does not verify: line {report.first_bad_line}: "
                        f"{report.reason}. Refusing to continue a damaged chain; move the file "
                        f"aside (and keep it for investigation), then start again."
                    )
                self._recover(report.first_bad_line, scanned.bad_bytes)
        except BaseException as exc:
            self._fd = None
            os.close(fd)
            if isinstance(exc, OSError):
                raise ConfigurationError(f"cannot use audit log {str(self._path)!r}: {exc}") from exc
            raise

    def _recover(self, lineno: int, fragment: bytes) -> None:
        """Terminate a torn tail (if needed) and chain a recovery record past it: the tail is the
        lines from `lineno` to the end, `fragment` their bytes joined by newlines (several lines
        only if an earlier recovery was itself cut short)."""
        last = lineno + fragment.count(b"\n")
        lines = f"line {lineno}" if last == lineno else f"lines {lineno}-{last}"
        record, line = self._records.build(
            AuditEntry(
                "recovery",
                detail=f"torn {lines} ({len(fragment)} bytes) from an interrupted write; "
                "left in place, chain continues from the last good record",
                outcome="recovered",
                extra={
                    "torn_line": lineno,
                    "torn_bytes": len(fragment),
                    "torn_sha256": hashlib.sha256(fragment).hexdigest(),
                },
            ),
            self._seq,
            self._prev,
        )
        assert self._fd is not None
        size = os.fstat(self._fd).st_size
        needs_newline = size > 0 and last_byte(self._fd, size) != b"\n"
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
        return self._fd is None or self._closing

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
    def unusable(self) -> str | None:
        """Why no record can be written now (a failed write, closing, closed); None while records
        can be. What callers show a human who must know that the log is not recording."""
        if self._broken is not None:
            return f"audit log {str(self._path)!r} is unusable after a failed write: {self._broken}"
        if self.closed:
            return f"audit log {str(self._path)!r} is closed"
        return None

    @property
    def recovery_record(self) -> AuditRecord | None:
        """The recovery record written on open, if the file ended with a torn line."""
        return self._recovery

    # -- writing ---------------------------------------------------------------------------
    def _write(self, data: bytes, sync: bool = True) -> None:
        assert self._fd is not None
        view = memoryview(data)
        while view:
            written = self._disk.write(self._fd, view)
            view = view[written:]
        if sync:
            self._disk.fsync(self._fd)

    def _fsync_written(self) -> None:
        """fsync what was written without it (a group commit by the writer thread).

        Not under the lock: a stalled disk must not hold up callers handing records over (the event
        loop's `append_soon` and `append_async` take the lock briefly). The descriptor stays open
        meanwhile: `close` joins the writer thread before it closes it."""
        with self._lock:
            fd = self._fd
        if fd is None:
            raise AuditWriteError(f"audit log {str(self._path)!r} is closed")
        try:
            self._disk.fsync(fd)
        except OSError as exc:
            with self._lock:
                self._broken = str(exc)
            raise AuditWriteError(f"cannot fsync audit log {str(self._path)!r}: {exc}") from exc

    def append(self, entry: AuditEntry | str, /, **fields: Any) -> AuditRecord:
        """Write one record and fsync it; returns the record. Raises AuditWriteError on failure.

        Takes an `AuditEntry`, or an event name with the entry's other fields as keywords.
        After a write failure the log refuses further appends (the file may now end in a torn
        line; reopening recovers it), so callers fail closed instead of writing past a hole.
        """
        return self._append(entry_of(entry, fields), sync=True)

    def _append(self, entry: AuditEntry, *, sync: bool) -> AuditRecord:
        with self._lock:
            if self._fd is None:
                raise AuditWriteError(f"audit log {str(self._path)!r} is closed")
            if self._broken is not None:
                raise AuditWriteError(
                    f"audit log {str(self._path)!r} is unusable after an earlier write failure: {self._broken}"
                )
            record, line = self._records.build(entry, self._seq, self._prev)
            try:
                self._write(line, sync=sync)
            except OSError as exc:
                self._broken = str(exc)
                raise AuditWriteError(f"cannot write audit record to {str(self._path)!r}: {exc}") from exc
            self._seq, self._prev = record.seq, record.hash
            return record

    async def append_async(self, entry: AuditEntry | str, /, **fields: Any) -> AuditRecord:
        """`append` on the log's own writer thread, so the event loop never waits on disk.

        Returns once the record is written and fsync-ed (`Durability.NOW`). Records are written
        in the order of the calls. A record handed to the writer is always written — also when
        the caller is cancelled meanwhile (the event happened; the log must say so). A dedicated
        thread and a plain queue cost far less per record than a generic thread pool hop, which
        matters because every tool call writes one; under load one fsync serves many calls.
        """
        call = functools.partial(self._append, entry_of(entry, fields), sync=False)
        loop = asyncio.get_running_loop()
        future: asyncio.Future[AuditRecord] = loop.create_future()
        self._hand_over(Job(call, Durability.NOW, loop, future))
        return await asyncio.shield(future)

    def append_soon(self, entry: AuditEntry | str, /, **fields: Any) -> None:
        """Hand a record of a read-only call to the writer thread without waiting for it.

        It keeps its place after the records already queued and is written and fsync-ed within
        `commit_window_s` (`Durability.WINDOW`; sooner if a record that must be on disk follows).
        Raises `AuditWriteError` at once if the log is closed or broken, so a caller fails closed
        instead of answering calls the log can no longer record.
        """
        if self._broken is not None:
            raise AuditWriteError(
                f"audit log {str(self._path)!r} is unusable after an earlier write failure: {self._broken}"
            )
        call = functools.partial(self._append, entry_of(entry, fields), sync=False)
        self._hand_over(Job(call, Durability.WINDOW))

    def submit(self, entry: AuditEntry | str, /, **fields: Any) -> None:
        """From any thread, without waiting: hand a record to the writer thread (after the ones
        already queued), fsync-ed with its batch (`Durability.NOW`). For paths that must never
        wait on the disk or the event loop, such as the independent stop channel; a record that
        cannot be written is logged, and the log is then broken like after any failed write.
        Raises `AuditWriteError` if the log is closed."""
        call = functools.partial(self._append, entry_of(entry, fields), sync=False)
        self._hand_over(Job(call, Durability.NOW))

    def flush(self, timeout_s: float = 30.0) -> None:
        """Block until every record handed over so far is written and fsync-ed (window records
        included). For callers that read the file right after (tests, tools); not for the event
        loop. A closed log has nothing left to flush (closing wrote everything). Raises
        `AuditWriteError` if that fails, TimeoutError after ``timeout_s``."""
        if self._fd is None:
            return
        waiter: concurrent.futures.Future[None] = concurrent.futures.Future()
        self._hand_over(Job(lambda: None, Durability.NOW, waiter=waiter))
        try:
            waiter.result(timeout_s)
        except concurrent.futures.TimeoutError as exc:
            raise TimeoutError(f"audit log {str(self._path)!r} did not flush within {timeout_s:g} s") from exc

    def observe_writes(self, callback: Callable[[str, float], None] | None) -> None:
        """Tell `callback(durability, seconds)`, on the writer thread, how long each record took
        from hand-over to fsynced (the daemon's metrics). It must be quick; its failures are
        logged, never raised into the writer."""
        self._on_durable = callback

    def _durable(self, durability: str, seconds: float) -> None:
        callback = self._on_durable
        if callback is not None:
            callback(durability, seconds)

    @property
    def commit_window_s(self) -> float:
        """How long a read-only call's record may wait to be written and fsync-ed [s]; 0: every
        record is on disk before its caller is answered."""
        return self._window_s

    def _hand_over(self, job: Job) -> None:
        """Queue ``job`` on the writer thread (started on first use), or raise AuditWriteError if
        the log is closing or closed. Checked and queued under one lock that `close` also takes,
        so a job is either queued before the writer's stop marker (and written) or refused."""
        with self._handover_lock:
            if self._closing:
                raise AuditWriteError(f"audit log {self.path} is closing")
            if self._writer_thread is None:
                if self._fd is None:
                    raise AuditWriteError(f"audit log {self.path} is closed")
                self._writer_thread = Writer(self._fsync_written, self._window_s, on_durable=self._durable)
            self._writer_thread.put(job)

    # -- reading ---------------------------------------------------------------------------
    def tail(self, n: int = 20) -> list[dict[str, Any]]:
        """The last ``n`` records (clamped to 1..1000), oldest first."""
        with self._lock:
            if self._fd is None:
                raise AuditWriteError(f"audit log {str(self._path)!r} is closed")
            with os.fdopen(os.dup(self._fd), "rb") as stream:
                lines = tail_lines(stream, clamp_tail(n))
        return decode_records(lines)

    async def tail_async(self, n: int = 20) -> list[dict[str, Any]]:
        """`tail` in call order: the records handed to the writer before this call are in it."""
        loop = asyncio.get_running_loop()
        future: asyncio.Future[list[dict[str, Any]]] = loop.create_future()
        self._hand_over(Job(functools.partial(self.tail, n), Durability.NONE, loop, future))
        return await asyncio.shield(future)

    # -- closing ---------------------------------------------------------------------------
    def close(self) -> None:
        """Release the file. Idempotent; writes nothing (a ``shutdown`` record is the caller's).

        Records already handed to the writer thread are written first."""
        with self._handover_lock:
            self._closing = True  # a record handed over from another thread from now on is refused, not lost
            writer, self._writer_thread = self._writer_thread, None
        if writer is not None:
            writer.stop()
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
