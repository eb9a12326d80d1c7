"""A disk that fills up, for the audit log's `disk` seam (`armwarden.audit.Disk`).

Why: a full audit disk is a fault the daemon must survive honestly, and reproducing it with a
real tiny file system needs root (a tmpfs or loop mount). `SmallDisk` behaves like the kernel
does on a full file system: a write takes as many bytes as still fit and returns that count, and
a write when nothing fits fails with ENOSPC; fsync passes through. Safe to fill from any thread.
"""

from __future__ import annotations

import errno
import os
import threading


class SmallDisk:
    """The real file system with `free_bytes` left (None: unlimited until `fill`)."""

    def __init__(self, free_bytes: int | None = None) -> None:
        self._free = free_bytes
        self._lock = threading.Lock()
        #: how many writes were refused with ENOSPC
        self.refused = 0

    def fill(self) -> None:
        """From now on nothing fits: every write fails with ENOSPC."""
        with self._lock:
            self._free = 0

    def write(self, fd: int, data: memoryview) -> int:
        with self._lock:
            if self._free is None:
                return os.write(fd, data)
            if self._free == 0:
                self.refused += 1
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            written = os.write(fd, data[: self._free])
            self._free -= written
            return written

    def fsync(self, fd: int) -> None:
        os.fsync(fd)
