"""The audit log's file: opening it for one writer, and the disk it writes through.

Apart from the log so that what touches the file system before a record exists (the advisory
lock, the directory fsync, the scan of what is already there) and the seam tests use to fill
the disk are read in one place.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import Protocol

from armwarden.audit.verify import Scan, scan
from armwarden.core.errors import ConfigurationError

try:  # POSIX advisory lock: one writer per log file.
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX
    fcntl = None  # type: ignore[assignment]

__all__ = ["OS_DISK", "Disk", "last_byte", "open_log_file"]


class Disk(Protocol):
    """What the log asks of the file system once the file is open: write some bytes (``os.write``
    semantics: may write fewer than given) and fsync. The default is the OS (`OS_DISK`); tests
    inject a disk that fills up, so a full disk is reproduced without root or a real tiny file
    system."""

    def write(self, fd: int, data: memoryview) -> int: ...

    def fsync(self, fd: int) -> None: ...


class _OsDisk:
    """The real file system (looked up at call time, so a patched ``os.fsync`` still applies)."""

    def write(self, fd: int, data: memoryview) -> int:
        return os.write(fd, data)

    def fsync(self, fd: int) -> None:
        os.fsync(fd)


OS_DISK: Disk = _OsDisk()


def open_log_file(path: Path, key: bytes | None) -> tuple[int, Scan]:
    """Open (creating it with mode 0600) and lock the log file, and scan what it holds; the
    descriptor is the caller's. `ConfigurationError` says why not (the directory is missing, the
    path is not a regular file, another writer holds it); nothing is left open then."""
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
            scanned = scan(stream, key)
    except BaseException as exc:
        os.close(fd)
        if isinstance(exc, OSError):
            raise ConfigurationError(f"cannot use audit log {str(path)!r}: {exc}") from exc
        raise
    return fd, scanned


def last_byte(fd: int, size: int) -> bytes:
    return os.pread(fd, 1, size - 1)


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
