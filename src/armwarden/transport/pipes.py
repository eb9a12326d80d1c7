"""Stdin and stdout served from the event loop, without a thread round trip per message.

The SDK's stdio transport reads every line and writes every answer through `anyio.wrap_file`:
each `readline`, `write` and `flush` runs on a worker thread, three thread round trips per
request, which under the interpreter lock cost more than a state poll's own work. When stdin and
stdout are pipes or sockets of this process's own (what every MCP client launches a server with;
Node-based clients pass socket pairs), `claimed_pipes` takes them as the SDK would — fd 0 then
reads /dev/null and fd 1 writes to stderr while serving, so stray output from a library never
reaches the wire; both are restored on exit — and serves private duplicates from the event loop
(`PipeLineReader`, `PipeWriter`). The SDK's own reader and writer tasks still parse and
serialise every message, so what goes over the wire is what the SDK would send.

The descriptors' flags are never touched: an `O_NONBLOCK` would be shared with every process
holding the same pipe (a launching shell, `npx`, `uv run`) and would outlive a killed daemon.
Sockets are read and written with `MSG_DONTWAIT`; pipes through a private non-blocking pipe with
`splice(SPLICE_F_NONBLOCK)`, non-blocking per call (see `Wire`). The loop gets a turn after every
read, and a line longer than `MAX_LINE_BYTES` is dropped and replaced by one the SDK cannot parse
(it is answered with a parse error), so neither a client's endless line nor its flood can hold
the loop or exhaust memory.

Anything else — a terminal, a regular file, /dev/null, a descriptor shared with stderr — is left
to the SDK's threads, as is everything when claiming fails.
"""

from __future__ import annotations

import asyncio
import codecs
import io
import logging
import os
import socket
import stat
import sys
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress

__all__ = ["MAX_LINE_BYTES", "TOO_LONG", "LineSplitter", "PipeLineReader", "PipeWriter", "Wire", "claimed_pipes", "own_pipe"]

logger = logging.getLogger(__name__)

#: bytes asked for per read (a whole request fits in one read almost always)
READ_CHUNK = 1 << 16
#: the longest line kept [bytes]; requests are small (the largest, a waypoint plan, is a few KiB)
MAX_LINE_BYTES = 1 << 22
#: what stands for a dropped line: not JSON, so the SDK's reader reports it and the gate answers -32700
TOO_LONG = "<a line longer than the limit was dropped>\n"


def own_pipe(fd: int, stderr_fd: int = 2) -> bool:
    """Whether `fd` is a pipe or socket that is not also this process's stderr (`stderr_fd`)."""
    try:
        info, err = os.fstat(fd), os.fstat(stderr_fd)
    except OSError:
        return False
    if not (stat.S_ISFIFO(info.st_mode) or stat.S_ISSOCK(info.st_mode)):
        return False
    if stat.S_ISSOCK(info.st_mode) and socket.getdefaulttimeout() is not None:
        return False  # a socket object would set O_NONBLOCK on the shared descriptor (see `Wire`)
    if stat.S_ISFIFO(info.st_mode) and not hasattr(os, "splice"):
        return False  # a pipe is served through splice (Linux; see `Wire`)
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
    still a line. Work is linear in the input (a line's pieces are joined once, when it ends).

    A line longer than `max_line_bytes` (its decoded text, counted in UTF-8 bytes) is not kept:
    the rest of it is dropped as it arrives, and `TOO_LONG` stands for it (see the module docstring)."""

    def __init__(self, max_line_bytes: int = 0) -> None:
        self._decoder = io.IncrementalNewlineDecoder(codecs.getincrementaldecoder("utf-8")(errors="replace"),
                                                     translate=True)
        self._pieces: list[str] = []
        self._held = 0  # bytes of the line being received
        self._max = max_line_bytes
        self._dropping = False

    def feed(self, data: bytes) -> list[str]:
        return self._split(self._decoder.decode(data))

    def finish(self) -> list[str]:
        """The lines the end of the input completes (the last one without a newline)."""
        lines = self._split(self._decoder.decode(b"", final=True))  # a held-back CR becomes a newline
        if self._dropping:
            lines.append(TOO_LONG)
        elif self._pieces:
            lines.append("".join(self._pieces))
        self._pieces, self._held, self._dropping = [], 0, False
        return lines

    def _split(self, text: str) -> list[str]:
        lines: list[str] = []
        *complete, rest = text.split("\n")
        for piece in complete:  # each ends a line
            self._hold(piece)
            lines.append(TOO_LONG if self._dropping else "".join(self._pieces) + "\n")
            self._pieces, self._held, self._dropping = [], 0, False
        self._hold(rest)
        return lines

    def _hold(self, piece: str) -> None:
        """Add `piece` to the line being received, or start dropping it once it is too long."""
        if self._dropping or not piece:
            return
        self._held += len(piece.encode("utf-8", "surrogatepass"))
        if self._max and self._held > self._max:
            self._pieces, self._dropping = [], True
        else:
            self._pieces.append(piece)


class PipeLineReader:
    """The lines of a pipe or socket (see `LineSplitter`), read from the event loop without ever
    blocking it (see the module docstring)."""

    def __init__(self, fd: int, max_line_bytes: int = 0) -> None:
        self._wire = Wire(fd)
        self._splitter = LineSplitter(max_line_bytes or MAX_LINE_BYTES)
        self._lines: deque[str] = deque()
        self._ended = False

    def __aiter__(self) -> PipeLineReader:
        return self

    async def __anext__(self) -> str:
        while not self._lines:
            if self._ended:
                raise StopAsyncIteration
            data = await self._wire.read(READ_CHUNK)
            if data:
                self._lines.extend(self._splitter.feed(data))
                await asyncio.sleep(0)  # a turn for the loop after every read: a flood cannot hold it
            else:
                self._ended = True
                self._lines.extend(self._splitter.finish())
        return self._lines.popleft()

    def close(self) -> None:
        self._wire.close()


class PipeWriter:
    """Writes text to a pipe or socket as UTF-8, whole, from the event loop without blocking it."""

    def __init__(self, fd: int) -> None:
        self._wire = Wire(fd)

    async def write(self, text: str) -> int:
        view = memoryview(text.encode("utf-8"))
        while view:
            view = view[await self._wire.write(view):]
        return len(text)

    async def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self) -> None:
        self._wire.close()


class Wire:
    """One descriptor, read or written without blocking whatever its flags, and without changing
    them: a socket with `MSG_DONTWAIT`; a pipe through a private non-blocking pipe of ours (the
    stage) with `splice(SPLICE_F_NONBLOCK)`, which never waits on either pipe — even if another
    process shares the wire and empties or fills it between a readiness report and our call."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        is_socket = stat.S_ISSOCK(os.fstat(fd).st_mode)
        # a socket object for MSG_DONTWAIT, on a duplicate of its own (closing it closes only that)
        self._socket = socket.socket(fileno=os.dup(fd)) if is_socket else None
        self._stage = None if is_socket else os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._staged = 0  # bytes in the stage on their way out (written, not yet spliced to the wire)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
        for end in self._stage or ():
            with suppress(OSError):
                os.close(end)
        self._stage = None

    async def read(self, size: int) -> bytes:
        """Up to `size` bytes (at most a pipe's capacity); b"" at the end of the input."""
        loop = asyncio.get_running_loop()
        while True:
            if self._socket is not None:
                with suppress(BlockingIOError):
                    return self._socket.recv(size, socket.MSG_DONTWAIT)
            else:
                stage_out, stage_in = self._require_stage()
                with suppress(BlockingIOError):
                    moved = os.splice(self.fd, stage_in, size, flags=os.SPLICE_F_NONBLOCK)
                    return os.read(stage_out, moved) if moved else b""  # 0: every writer is gone
            await _ready(self.fd, loop.add_reader, loop.remove_reader)

    async def write(self, data: memoryview) -> int:
        """Write some of `data` to the wire; how many bytes of it were taken (none only when bytes a
        cancelled write left staged went out first: the caller writes again)."""
        loop = asyncio.get_running_loop()
        if self._socket is not None:
            while True:
                with suppress(BlockingIOError):
                    return self._socket.send(data, socket.MSG_DONTWAIT)
                await _ready(self.fd, loop.add_writer, loop.remove_writer)
        stage_out, stage_in = self._require_stage()
        taken = 0
        if not self._staged:  # (a cancelled write may have left bytes staged: those go first)
            taken = self._staged = os.write(stage_in, data)  # private and empty: takes up to its capacity
        while self._staged:
            try:
                self._staged -= os.splice(stage_out, self.fd, self._staged, flags=os.SPLICE_F_NONBLOCK)
            except BlockingIOError:
                await _ready(self.fd, loop.add_writer, loop.remove_writer)
        return taken

    def _require_stage(self) -> tuple[int, int]:
        if self._stage is None:
            raise ValueError("this wire is closed")
        return self._stage


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
    wires: list[int] = []
    diverted: list[int] = []
    try:
        wires.append(fcntl.fcntl(0, fcntl.F_DUPFD_CLOEXEC, 3))
        wires.append(fcntl.fcntl(1, fcntl.F_DUPFD_CLOEXEC, 3))
        null = os.open(os.devnull, os.O_RDONLY)
        try:
            os.dup2(null, 0)
        finally:
            os.close(null)
        diverted.append(0)
        os.dup2(2, 1)
        diverted.append(1)
    except OSError as exc:  # as the SDK: whatever cannot be claimed is served as it is, by its threads
        _give_back(wires, diverted)
        logger.warning("stdio: cannot claim stdin and stdout (%s); the SDK's threads serve them", exc)
        yield None
        return
    logger.info("stdio: serving stdin and stdout from the event loop")
    try:
        yield wires[0], wires[1]
    finally:
        _give_back(wires, diverted)


def _give_back(wires: list[int], diverted: list[int]) -> None:
    """Point every diverted fd back at its wire, then close the private duplicates."""
    for fd in diverted:
        try:
            os.dup2(wires[fd], fd)
        except OSError:  # pragma: no cover - the descriptor itself is gone
            logger.warning("could not give fd %d back its stdio wire", fd)
    for wire in wires:
        with suppress(OSError):
            os.close(wire)
