"""Stdin and stdout served from the event loop, without a thread round trip per message.

The SDK's stdio transport reads every line and writes every answer through `anyio.wrap_file`:
each `readline`, `write` and `flush` runs on a worker thread, three thread round trips per
request, which under the interpreter lock cost more than a state poll's own work. When stdin and
stdout are pipes or sockets of this process's own (what every MCP client launches a server with),
`claimed_pipes` takes them as the SDK would — fd 0 then reads /dev/null and fd 1 writes to stderr
while serving, so stray output from a library never reaches the wire; both are restored on exit —
and serves private, non-blocking duplicates from the event loop (`PipeLineReader`,
`PipeWriter`). The SDK's own reader and writer tasks still parse and serialise every message, so
what goes over the wire is byte for byte what the SDK would send.

Anything else — a terminal, a regular file, /dev/null, a descriptor shared with stderr (where a
non-blocking flag would leak into the log's writes) — is left to the SDK's threads.
"""

from __future__ import annotations

import asyncio
import codecs
import io
import logging
import os
import stat
import sys
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress

__all__ = ["LineSplitter", "PipeLineReader", "PipeWriter", "claimed_pipes", "own_pipe"]

logger = logging.getLogger(__name__)

#: bytes asked for per read (a whole request fits in one read almost always)
READ_CHUNK = 1 << 16


def own_pipe(fd: int, stderr_fd: int = 2) -> bool:
    """Whether `fd` is a pipe or socket that is not also this process's stderr (`stderr_fd`)."""
    try:
        info, err = os.fstat(fd), os.fstat(stderr_fd)
    except OSError:
        return False
    if not (stat.S_ISFIFO(info.st_mode) or stat.S_ISSOCK(info.st_mode)):
        return False
    return (info.st_dev, info.st_ino) != (err.st_dev, err.st_ino)


async def _ready(fd: int, add: Callable[..., None], remove: Callable[[int], bool]) -> None:
    """Wait until the loop reports `fd` ready (`add` is the loop's add_reader or add_writer)."""
    future = asyncio.get_running_loop().create_future()

    def wake() -> None:
        if not future.done():
            future.set_result(None)

    add(fd, wake)
    try:
        await future
    finally:
        remove(fd)


class LineSplitter:
    """Bytes in, lines out, as the SDK's stdin wrapper (`io.TextIOWrapper`, UTF-8 with undecodable
    bytes replaced, universal newlines) yields them: each line ends with a newline, a character
    or a CR LF split between two reads is joined, and at the end an unterminated last line is
    still a line."""

    def __init__(self) -> None:
        self._decoder = io.IncrementalNewlineDecoder(codecs.getincrementaldecoder("utf-8")(errors="replace"),
                                                     translate=True)
        self._partial = ""

    def feed(self, data: bytes) -> list[str]:
        *complete, self._partial = (self._partial + self._decoder.decode(data)).split("\n")
        return [line + "\n" for line in complete]

    def finish(self) -> list[str]:
        """The lines the end of the input completes (at most one, without a newline)."""
        tail = self._partial + self._decoder.decode(b"", final=True)  # a held-back CR becomes a newline
        self._partial = ""
        *complete, last = tail.split("\n")
        return [line + "\n" for line in complete] + ([last] if last else [])


class PipeLineReader:
    """The lines of a non-blocking descriptor (see `LineSplitter`), read from the event loop."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._splitter = LineSplitter()
        self._lines: deque[str] = deque()
        self._ended = False

    def __aiter__(self) -> PipeLineReader:
        return self

    async def __anext__(self) -> str:
        while not self._lines:
            if self._ended:
                raise StopAsyncIteration
            await self._fill()
        return self._lines.popleft()

    async def _fill(self) -> None:
        try:
            data = os.read(self._fd, READ_CHUNK)
        except BlockingIOError:
            loop = asyncio.get_running_loop()
            await _ready(self._fd, loop.add_reader, loop.remove_reader)
            return
        if data:
            self._lines.extend(self._splitter.feed(data))
        else:
            self._ended = True
            self._lines.extend(self._splitter.finish())


class PipeWriter:
    """Writes text to a non-blocking descriptor as UTF-8, whole, from the event loop."""

    def __init__(self, fd: int) -> None:
        self._fd = fd

    async def write(self, text: str) -> int:
        view = memoryview(text.encode("utf-8"))
        loop = asyncio.get_running_loop()
        while view:
            try:
                written = os.write(self._fd, view)
            except BlockingIOError:  # the client is not reading yet: wait, never block the loop
                await _ready(self._fd, loop.add_writer, loop.remove_writer)
                continue
            view = view[written:]
        return len(text)

    async def flush(self) -> None:
        """Nothing is buffered here."""


@contextmanager
def claimed_pipes() -> Iterator[tuple[int, int] | None]:
    """(reader fd, writer fd) while serving, or None if stdin and stdout are not pipes of their
    own (then the SDK's transport serves them). See the module docstring."""
    if sys.platform == "win32" or not (own_pipe(0) and own_pipe(1)):
        logger.info("stdio: stdin and stdout are not pipes of their own; the SDK's threads serve them")
        yield None
        return
    import fcntl  # POSIX only, as the branch above

    with suppress(ValueError, OSError):
        sys.stdout.flush()  # nothing of ours should be buffered, but nothing may be lost either
    try:
        wire_in = fcntl.fcntl(0, fcntl.F_DUPFD_CLOEXEC, 3)
    except OSError as exc:
        logger.warning("stdio: cannot duplicate stdin (%s); the SDK's threads serve it", exc)
        yield None
        return
    try:
        wire_out = fcntl.fcntl(1, fcntl.F_DUPFD_CLOEXEC, 3)
    except OSError as exc:
        os.close(wire_in)
        logger.warning("stdio: cannot duplicate stdout (%s); the SDK's threads serve it", exc)
        yield None
        return
    try:
        null = os.open(os.devnull, os.O_RDONLY)
        try:
            os.dup2(null, 0)
        finally:
            os.close(null)
        os.dup2(2, 1)
        os.set_blocking(wire_in, False)
        os.set_blocking(wire_out, False)
        logger.info("stdio: serving stdin and stdout from the event loop")
        yield wire_in, wire_out
    finally:
        for fd, wire in ((0, wire_in), (1, wire_out)):
            with suppress(OSError):
                os.set_blocking(wire, True)
            try:
                os.dup2(wire, fd)
            except OSError:  # pragma: no cover - the descriptor itself is gone
                logger.warning("could not give fd %d back its stdio wire", fd)
            with suppress(OSError):
                os.close(wire)
