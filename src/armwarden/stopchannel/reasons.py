"""The reason of ``armwarden estop --pid PID --reason TEXT``, handed to the daemon beside SIGUSR1.

A signal carries no text. `sigqueue(3)` would carry one integer, and Python has no binding to
send it; the stop channel carries text but needs a token and a port. So the command signals,
then writes the reason to a file of its own, named for the daemon's process id, in a directory
only this user can use (`reason_directory`). The daemon's signal thread issues the stop,
and its recorder then waits briefly for the reason files of that stop and takes them into the
audit record (`armwarden.stopchannel.signals`): the stop never waits for, reads or depends on a
reason (a missing, late, refused or unreadable one leaves the record's reason "SIGUSR1 received").

The files are text and nothing else: read only from a directory and files owned by the daemon's
user with no group or other access (opened without following links, never a FIFO), at most
`MAX_REASON_BYTES`, cleaned to one printable line of at most `REASON_LIMIT` characters, removed
once read, and ignored when older than `MAX_REASON_AGE_S` (written for a stop that was never
sent, or for an earlier process with the same id).

The directory: ``$XDG_RUNTIME_DIR/armwarden`` when that variable names a private directory of
this user, else ``/run/user/<uid>/armwarden`` when that is one, else ``/tmp/armwarden-<uid>``.
The runtime directories come first because no one else can create anything in them; in the
shared ``/tmp`` another local user can create ``armwarden-<uid>`` first, and the checks then
refuse it (the command says so on stderr; the stop still goes out). The command writes to the
first; the daemon reads all of them, since it may run without the shell's ``XDG_RUNTIME_DIR``
(a service) or before ``/run/user/<uid>`` exists. Both sides must see the same directories:
under systemd's ``PrivateTmp`` (for the ``/tmp`` fallback) or as another user (root signalling a
user's daemon) the reason is lost, the stop is not.

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
#: where the per-user runtime directories are, ``/run/user/<uid>`` (systemd-logind)
RUNTIME_ROOT = Path("/run/user")
#: the shared temporary directory, the last resort
SHARED_TMP = Path("/tmp")
_SUFFIX = ".reason"


class ReasonDirectoryRefused(PermissionError):
    """The reason directory is not a directory of this user alone: another user may have made it."""


def reason_directories() -> list[Path]:
    """Every directory a reason for this user's daemons may be in, the one to write to first:
    ``$XDG_RUNTIME_DIR/armwarden``, ``/run/user/<uid>/armwarden`` (each only when its parent is a
    private directory of this user), ``/tmp/armwarden-<uid>``."""
    uid = os.geteuid()
    found: list[Path] = []
    runtime = os.environ.get("XDG_RUNTIME_DIR", "")
    if runtime and os.path.isabs(runtime) and _refusal(Path(runtime)) is None:
        found.append(Path(runtime) / "armwarden")
    if _refusal(RUNTIME_ROOT / str(uid)) is None:
        found.append(RUNTIME_ROOT / str(uid) / "armwarden")
    found.append(SHARED_TMP / f"armwarden-{uid}")
    return list(dict.fromkeys(found))


def reason_directory() -> Path:
    """Where ``armwarden estop --pid`` writes its reason (the first of `reason_directories`)."""
    return reason_directories()[0]


def _prefix(pid: int) -> str:
    return f"estop-{pid}-"


def _refusal(directory: Path) -> str | None:
    """Why `directory` is not a real directory of this user that no one else may use, or None
    when it is one. OSError when it cannot be looked at."""
    try:
        info = os.lstat(directory)
    except FileNotFoundError:
        return "it does not exist"
    if not stat.S_ISDIR(info.st_mode):
        return "it is not a directory"
    if info.st_uid != os.geteuid():
        return f"it belongs to uid {info.st_uid}, not to this user (uid {os.geteuid()})"
    if info.st_mode & 0o077:
        return f"group or others may use it (mode {stat.S_IMODE(info.st_mode):04o})"
    return None


def _check_private_directory(directory: Path) -> None:
    """OSError unless `directory` is a real directory of this user that no one else may use:
    FileNotFoundError when there is none, `ReasonDirectoryRefused` when it is not ours alone."""
    why = _refusal(directory)
    if why == "it does not exist":
        raise FileNotFoundError(f"{directory} does not exist")
    if why is not None:
        raise ReasonDirectoryRefused(
            f"reason directory {directory} refused: {why}; another local user may have created it. Remove it, or "
            "set XDG_RUNTIME_DIR to a directory of yours (for the daemon too)")


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


def _reason_files(pid: int, directory: Path | None) -> list[Path]:
    """The reason files for `pid` in `directory` (None: every one of `reason_directories`). A
    directory that is missing or refused is left out (refusals are said by `discard_reasons`, at
    the daemon's start, and by the command)."""
    paths: list[Path] = []
    for place in reason_directories() if directory is None else [directory]:
        try:
            _check_private_directory(place)
            paths.extend(_files_for(pid, place))
        except FileNotFoundError:
            continue
        except OSError as exc:
            logger.debug("e-stop reasons in %s not read: %s", place, exc)
    return paths


def take_reasons(pid: int | None = None, directory: Path | None = None, *, signalled_from_ns: int | None = None,
                 signalled_before_ns: int | None = None) -> str | None:
    """The reasons written for `pid` (default: this process) whose signal was sent in
    [`signalled_from_ns`, `signalled_before_ns`) (``time.monotonic_ns()``; None: unbounded), oldest
    signal first and joined by "; " (at most `REASON_LIMIT` characters), removing them; None when
    there is none. Read from `directory`, or from every one of `reason_directories`. Later ones
    are left for a later stop; earlier ones came too late for theirs and are removed unread.
    Never raises: a refused or unreadable reason is left out."""
    pid = os.getpid() if pid is None else pid
    now = time.time()
    mine: list[tuple[int, str, Path]] = []
    for path in _reason_files(pid, directory):
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
    id, so none is taken for a later stop, from `directory` or every one of `reason_directories`;
    say (a warning) when the directory the command writes to is refused. Never raises."""
    pid = os.getpid() if pid is None else pid
    target = reason_directory() if directory is None else directory
    try:
        _check_private_directory(target)
    except FileNotFoundError:
        pass
    except OSError as exc:
        logger.warning("the reasons of `armwarden estop --pid` will be lost: %s", exc)
    for path in _reason_files(pid, directory):
        with contextlib.suppress(OSError):
            os.unlink(path)


__all__ = [
    "MAX_REASON_AGE_S",
    "MAX_REASON_BYTES",
    "ReasonDirectoryRefused",
    "discard_reasons",
    "reason_directories",
    "reason_directory",
    "take_reasons",
    "write_reason",
]
