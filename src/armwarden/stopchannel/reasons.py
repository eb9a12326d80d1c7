"""The reason of ``armwarden estop --pid PID --reason TEXT``, handed to the daemon beside SIGUSR1.

A signal carries no text. `sigqueue(3)` would carry one integer, and Python has no binding to
send it; the stop channel carries text but needs a token and a port. So the command signals,
then writes the reason to a file of its own, named for the daemon's process id, in a directory
only this user can use (``/tmp/armwarden-<uid>``). The daemon's signal thread issues the stop,
and its recorder then waits briefly for the reason files of that stop and takes them into the
audit record (`armwarden.stopchannel.signals`): the stop never waits for, reads or depends on a
reason (a missing, late, refused or unreadable one leaves the record's reason "SIGUSR1 received").

The files are text and nothing else: read only from a directory and files owned by the daemon's
user with no group or other access (opened without following links, never a FIFO), at most
`MAX_REASON_BYTES`, cleaned to one printable line of at most `REASON_LIMIT` characters, removed
once read, and ignored when older than `MAX_REASON_AGE_S` (written for a stop that was never
sent, or for an earlier process with the same id). Both sides must see the same ``/tmp``: under
systemd's ``PrivateTmp`` or as another user (root signalling a user's daemon) the reason is lost,
the stop is not.

Which stop a reason belongs to: signals carry nothing and coalesce, so a file is matched to a stop
by time. Its name carries the ``CLOCK_MONOTONIC`` time (shared by all processes of the machine)
its command took just before signalling; the daemon's signal thread notes the same clock when a
signal wakes it, after clearing the signal's flag. A command's signal sets that flag after the
time in its file, so the stop that answers it woke later: each stop takes the files signalled
before it woke and after the previous stop woke (files signalled during a stop are the next
stop's, whenever they were written). Not the file's mtime: it comes from a coarse clock (a
jiffy on Linux) and says when the file was written, not when its signal was sent.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import stat
import time
from pathlib import Path

from armwarden.safety.estop import flatten_reason
from armwarden.stopchannel.wire import REASON_LIMIT

logger = logging.getLogger(__name__)

#: largest reason file read [bytes]; a larger one is refused unread
MAX_REASON_BYTES = 2048
#: a reason file older than this when the stop is handled belongs to no stop of now [s]
MAX_REASON_AGE_S = 60.0
_SUFFIX = ".reason"


def reason_directory() -> Path:
    """Where reasons for this user's daemons are written: the same for the command and the daemon."""
    return Path("/tmp") / f"armwarden-{os.geteuid()}"


def _prefix(pid: int) -> str:
    return f"estop-{pid}-"


def _check_private_directory(directory: Path) -> None:
    """OSError unless `directory` is a real directory of this user that no one else may use."""
    info = os.lstat(directory)
    if not stat.S_ISDIR(info.st_mode):
        raise NotADirectoryError(f"{directory} is not a directory")
    if info.st_uid != os.geteuid() or info.st_mode & 0o077:
        raise PermissionError(f"{directory} must belong to this user with no group or other access")


def write_reason(pid: int, reason: str, directory: Path | None = None, *, signalled_ns: int | None = None) -> Path:
    """Write `reason` for the daemon `pid` (owner-only, complete before it appears under its name)
    and return the file's path. `signalled_ns`: ``time.monotonic_ns()`` taken just before the
    signal was sent (None: now, for a reason written before signalling). Raises OSError when it
    cannot."""
    directory = reason_directory() if directory is None else directory
    signalled_ns = time.monotonic_ns() if signalled_ns is None else signalled_ns
    with contextlib.suppress(FileExistsError):
        os.mkdir(directory, 0o700)
    _check_private_directory(directory)
    data = flatten_reason(reason, REASON_LIMIT).encode("utf-8")
    name = f"{_prefix(pid)}{signalled_ns}-{secrets.token_hex(4)}"
    partial, final = directory / f".{name}.tmp", directory / f"{name}{_SUFFIX}"
    fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(data)
        os.rename(partial, final)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(partial)
        raise
    return final


def _read_one(path: Path, now: float) -> str | None:
    """The cleaned text of one reason file, or None when it is refused. Removes it."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as exc:
        logger.warning("e-stop reason %s not read: %s", path, exc)
        return None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_uid != os.geteuid() or info.st_mode & 0o077:
            logger.warning("e-stop reason %s refused: not a regular file of this user with owner-only access", path)
            return None
        if info.st_size > MAX_REASON_BYTES:
            logger.warning("e-stop reason %s refused: larger than %d bytes", path, MAX_REASON_BYTES)
            return None
        if now - info.st_mtime > MAX_REASON_AGE_S:
            return None  # for a stop long past, or never sent
        data = os.read(fd, MAX_REASON_BYTES + 1)
    except OSError as exc:
        logger.warning("e-stop reason %s not read: %s", path, exc)
        return None
    finally:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(path)
    return flatten_reason(data[:MAX_REASON_BYTES], REASON_LIMIT)


def _files_for(pid: int, directory: Path) -> list[Path]:
    prefix = _prefix(pid)
    with os.scandir(directory) as entries:
        return [Path(entry.path) for entry in entries if entry.name.startswith(prefix) and entry.name.endswith(_SUFFIX)]


def _signalled_ns(path: Path, pid: int) -> int | None:
    """The signalling time in a reason file's name, or None when the name carries none."""
    stamp = path.name[len(_prefix(pid)):].split("-", 1)[0]
    return int(stamp) if stamp.isascii() and stamp.isdigit() else None


def take_reasons(pid: int | None = None, directory: Path | None = None, *, signalled_from_ns: int | None = None,
                 signalled_before_ns: int | None = None) -> str | None:
    """The reasons written for `pid` (default: this process) whose signal was sent in
    [`signalled_from_ns`, `signalled_before_ns`) (``time.monotonic_ns()``; None: unbounded), oldest
    signal first and joined by "; " (at most `REASON_LIMIT` characters), removing them; None when
    there is none. Later ones are left for a later stop; earlier ones came too late for theirs and
    are removed unread. Never raises: a refused or unreadable reason is logged and left out."""
    pid = os.getpid() if pid is None else pid
    directory = reason_directory() if directory is None else directory
    try:
        _check_private_directory(directory)
        paths = _files_for(pid, directory)
    except FileNotFoundError:
        return None
    except OSError as exc:
        logger.warning("e-stop reasons in %s not read: %s", directory, exc)
        return None
    now = time.time()
    mine: list[tuple[int, str, Path]] = []
    for path in paths:
        signalled_ns = _signalled_ns(path, pid)
        if signalled_before_ns is not None and signalled_ns is not None and signalled_ns >= signalled_before_ns:
            continue  # its signal came after this stop began: the next stop's
        if signalled_ns is None or (signalled_from_ns is not None and signalled_ns < signalled_from_ns):
            why = "names no signalling time" if signalled_ns is None else "came after its stop was recorded"
            logger.warning("e-stop reason %s left out: it %s", path, why)
            with contextlib.suppress(OSError):
                os.unlink(path)
            continue
        mine.append((signalled_ns, path.name, path))
    texts = [text for _, _, path in sorted(mine) if (text := _read_one(path, now))]
    return flatten_reason("; ".join(texts), REASON_LIMIT) if texts else None


def discard_reasons(pid: int | None = None, directory: Path | None = None) -> None:
    """Remove reasons left for `pid` (default: this process) by an earlier process with the same
    id, so none is taken for a later stop. Never raises."""
    pid = os.getpid() if pid is None else pid
    directory = reason_directory() if directory is None else directory
    try:
        _check_private_directory(directory)
        paths = _files_for(pid, directory)
    except OSError:
        return
    for path in paths:
        with contextlib.suppress(OSError):
            os.unlink(path)


__all__ = ["MAX_REASON_AGE_S", "MAX_REASON_BYTES", "discard_reasons", "reason_directory", "take_reasons", "write_reason"]
