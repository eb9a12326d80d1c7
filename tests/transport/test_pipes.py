"""Stdin and stdout served from the event loop (`armwarden.transport.pipes`): lines as the SDK's
reader yields them, reads and writes that never block the loop, and the claim on fd 0 and fd 1."""

from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import subprocess
import sys
import threading
import time

import anyio
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.transport.pipes import TOO_LONG, LineSplitter, PipeLineReader, PipeWriter, own_pipe
from tests.helpers import REPO, child_env

#: byte pieces that exercise what the SDK's text wrapper does to a line: CR, CR LF, multi-byte
#: characters (split between reads below) and bytes that are not UTF-8
PIECES = [b"a", b"{}", b" ", b"\n", b"\r", b"\r\n", "é".encode(), "€".encode(), "🤖".encode(), b"\xff", b"\xc3", b"\x00"]


def sdk_lines(data: bytes) -> list[str]:
    """The lines the SDK's stdio transport reads from `data` (its wrapper, as `stdio_server` builds it)."""
    return list(io.TextIOWrapper(io.BytesIO(data), encoding="utf-8", errors="replace"))


@settings(max_examples=400, deadline=None)
@given(pieces=st.lists(st.sampled_from(PIECES), max_size=40), cuts=st.lists(st.integers(1, 7), max_size=40))
def test_lines_are_split_as_the_sdks_stdin_wrapper_splits_them_wherever_the_reads_end(pieces, cuts) -> None:
    data = b"".join(pieces)
    splitter, lines, start = LineSplitter(), [], 0
    for cut in cuts:
        lines += splitter.feed(data[start:start + cut])
        start += cut
    lines += splitter.feed(data[start:])
    lines += splitter.finish()
    assert lines == sdk_lines(data)


@settings(max_examples=300, deadline=None)
@given(pieces=st.lists(st.sampled_from(PIECES), max_size=40), cuts=st.lists(st.integers(1, 7), max_size=40),
       limit=st.integers(1, 24))
def test_a_line_over_the_limit_and_only_such_a_line_is_replaced_wherever_the_reads_end(pieces, cuts, limit) -> None:
    data = b"".join(pieces)
    splitter, lines, start = LineSplitter(max_line_bytes=limit), [], 0
    for cut in cuts:
        lines += splitter.feed(data[start:start + cut])
        start += cut
    lines += splitter.feed(data[start:]) + splitter.finish()
    assert lines == [line if len(line.rstrip("\n").encode()) <= limit else TOO_LONG for line in sdk_lines(data)]


def nonblocking_pipe() -> tuple[int, int]:
    read_end, write_end = os.pipe()
    os.set_blocking(read_end, False)
    os.set_blocking(write_end, False)
    return read_end, write_end


class Ticker:
    """Counts how often the event loop ran another task: proof that a read or write waited
    without blocking the loop."""

    def __init__(self) -> None:
        self.ticks = 0

    async def run(self) -> None:
        while True:
            self.ticks += 1
            await anyio.sleep(0.001)


@pytest.mark.anyio
async def test_a_reader_waits_for_a_line_without_blocking_the_loop() -> None:
    read_end, write_end = nonblocking_pipe()
    ticker = Ticker()
    try:
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(ticker.run)
            reader = PipeLineReader(read_end)
            with anyio.fail_after(5):
                async with anyio.create_task_group() as late:
                    late.start_soon(_write_later, write_end, b'{"jsonrpc":"2.0"}\r\n', 0.1)
                    assert await reader.__anext__() == '{"jsonrpc":"2.0"}\n'
            tasks.cancel_scope.cancel()
        assert ticker.ticks >= 20  # the loop kept running while the reader waited 0.1 s
    finally:
        os.close(read_end)
        os.close(write_end)


async def _write_later(fd: int, data: bytes, delay_s: float) -> None:
    await anyio.sleep(delay_s)
    os.write(fd, data)


@pytest.mark.anyio
async def test_a_line_longer_than_a_read_arrives_whole_and_the_last_line_needs_no_newline() -> None:
    read_end, write_end = nonblocking_pipe()
    os.set_blocking(write_end, True)  # the feeding thread blocks, not the loop
    long_line = b'{"pad":"' + b"x" * 300_000 + b'"}\n'

    def feed() -> None:
        os.write(write_end, long_line + b"last")
        os.close(write_end)

    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        with anyio.fail_after(10):
            lines = [line async for line in PipeLineReader(read_end)]
    finally:
        feeder.join(10)
        os.close(read_end)
    assert lines == [long_line.decode(), "last"]


@pytest.mark.anyio
async def test_a_writer_waits_for_a_slow_reader_without_blocking_the_loop() -> None:
    read_end, write_end = nonblocking_pipe()
    os.set_blocking(read_end, True)
    payload = "".join(f"{i:07d}\n" for i in range(125_000))  # 1 MB: sixteen times a pipe's buffer
    received = bytearray()

    def drain_slowly() -> None:
        while chunk := os.read(read_end, 65536):
            received.extend(chunk)
            time.sleep(0.005)

    drainer = threading.Thread(target=drain_slowly)
    ticker = Ticker()
    try:
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(ticker.run)
            drainer.start()
            with anyio.fail_after(20):
                assert await PipeWriter(write_end).write(payload) == len(payload)
            tasks.cancel_scope.cancel()
    finally:
        os.close(write_end)
        drainer.join(10)
        os.close(read_end)
    assert bytes(received) == payload.encode()
    assert ticker.ticks >= 10  # the loop ran while the writer waited for the reader


def test_only_pipes_and_sockets_not_shared_with_stderr_are_served_from_the_loop(tmp_path) -> None:
    read_end, write_end = os.pipe()
    left, right = socket.socketpair()
    regular = os.open(tmp_path / "file", os.O_CREAT | os.O_RDWR)
    null = os.open(os.devnull, os.O_RDONLY)
    try:
        other = os.dup(write_end)  # a stand-in for stderr that is not the wire
        assert own_pipe(read_end, stderr_fd=null) and own_pipe(left.fileno(), stderr_fd=null)
        assert not own_pipe(write_end, stderr_fd=other)  # the same pipe as "stderr": its flags are the log's too
        assert not own_pipe(regular, stderr_fd=null)
        assert not own_pipe(null, stderr_fd=regular)
        os.close(other)
    finally:
        for fd in (read_end, write_end, regular, null):
            os.close(fd)
        left.close()
        right.close()


CLAIM_PROBE = """
import json, os, sys
from armwarden.transport.pipes import claimed_pipes
with claimed_pipes() as wires:
    inside = {"claimed": wires is not None, "stdin_reads_eof": os.read(0, 16) == b"",
              "blocking": [os.get_blocking(fd) for fd in wires or ()]}
    os.write(1, b"stray output\\n")  # a library printing while serving: not on the wire
    os.write(wires[1], b"on the wire\\n")
after = {"blocking": [os.get_blocking(0), os.get_blocking(1)]}
os.write(1, b"after\\n")
sys.stderr.write(json.dumps({"inside": inside, "after": after}) + "\\n")
"""


@pytest.mark.parametrize("blocking", [True, False], ids=["blocking wire", "non-blocking wire"])
def test_claimed_pipes_divert_fd_0_and_1_while_serving_give_them_back_and_never_touch_their_flags(blocking) -> None:
    stdin_parent, stdin_child = socket.socketpair()  # as a Node client launches its server
    stdout_parent, stdout_child = socket.socketpair()
    for end in (stdin_child, stdout_child):  # the launcher keeps these: flags are shared with it
        os.set_blocking(end.fileno(), blocking)
    try:
        probe = subprocess.run([sys.executable, "-c", CLAIM_PROBE], stdin=stdin_child, stdout=stdout_child,
                               stderr=subprocess.PIPE, cwd=REPO, env=child_env(), timeout=60, check=True)
        assert [os.get_blocking(end.fileno()) for end in (stdin_child, stdout_child)] == [blocking, blocking]
        stdout_child.close()
        wire = b""
        while chunk := stdout_parent.recv(4096):
            wire += chunk
    finally:
        for end in (stdin_parent, stdin_child, stdout_parent, stdout_child):
            end.close()
    report = json.loads(probe.stderr.decode().strip().splitlines()[-1])
    assert report["inside"] == {"claimed": True, "stdin_reads_eof": True, "blocking": [blocking, blocking]}
    assert report["after"] == {"blocking": [blocking, blocking]}
    assert wire == b"on the wire\nafter\n"
    assert b"stray output" in probe.stderr


def test_a_line_longer_than_the_limit_is_dropped_and_stands_as_one_the_sdk_cannot_parse() -> None:
    splitter = LineSplitter(max_line_bytes=100)
    lines = splitter.feed(b'{"a":1}\n' + b"x" * 60)
    lines += splitter.feed(b"x" * 60)  # over the limit: dropped from here on, whatever else comes
    lines += splitter.feed(b"x" * 10_000)
    lines += splitter.feed(b'xx\n{"b":2}\n{"c"')
    lines += splitter.feed(b":3}")
    lines += splitter.finish()
    assert lines == ['{"a":1}\n', TOO_LONG, '{"b":2}\n', '{"c":3}']
    with pytest.raises(ValueError):
        json.loads(TOO_LONG)


CLAIM_FAILS_PROBE = """
import json, os, sys
real_open = os.open
def no_devnull(path, *args, **kwargs):
    if path == os.devnull:
        raise FileNotFoundError(2, "no /dev/null in this sandbox", path)
    return real_open(path, *args, **kwargs)
os.open = no_devnull
before = sorted(os.listdir("/proc/self/fd"))
from armwarden.transport.pipes import claimed_pipes
with claimed_pipes() as wires:
    claimed = wires is not None
os.write(1, b"still the wire\\n")
sys.stderr.write(json.dumps({"claimed": claimed, "fds_kept": sorted(os.listdir("/proc/self/fd")) == before}) + "\\n")
"""


def test_a_claim_that_fails_half_way_leaves_stdin_and_stdout_as_they_were_for_the_sdk(tmp_path) -> None:
    read_end, write_end = os.pipe()
    try:
        probe = subprocess.run([sys.executable, "-c", CLAIM_FAILS_PROBE], stdin=subprocess.PIPE, stdout=write_end,
                               stderr=subprocess.PIPE, cwd=REPO, env=child_env(), timeout=60, check=True)
        os.close(write_end)
        wire = os.read(read_end, 4096)
    finally:
        os.close(read_end)
    assert json.loads(probe.stderr.decode().strip().splitlines()[-1]) == {"claimed": False, "fds_kept": True}
    assert wire == b"still the wire\n"
    assert b"cannot claim stdin and stdout" in probe.stderr


@pytest.mark.anyio
async def test_a_writer_sharing_its_pipe_with_another_never_blocks_the_loop() -> None:
    """Another process holding the same pipe can fill it between a readiness report and our
    write; the write must then wait on the loop, never inside the kernel (the pipe's flags are
    blocking, as a launcher left them). The reader pauses 0.5 s after each pipeful."""
    read_end, write_end = os.pipe()
    stop = threading.Event()
    received = bytearray()

    def compete() -> None:  # another writer on the same pipe, filling every gap
        while not stop.is_set():
            try:
                os.write(write_end, b"#" * 4095)
            except OSError:
                return

    def drain_in_fits() -> None:  # a reader that takes one pipeful, then pauses
        while not stop.is_set():
            received.extend(os.read(read_end, 65536))
            stop.wait(0.5)

    threads = [threading.Thread(target=compete, daemon=True), threading.Thread(target=drain_in_fits, daemon=True)]
    gaps: list[float] = []

    async def watch() -> None:
        last = time.monotonic()
        while True:
            await anyio.sleep(0.005)
            now = time.monotonic()
            gaps.append(now - last)
            last = now

    writer = PipeWriter(write_end)
    try:
        for thread in threads:
            thread.start()
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(watch)
            started = time.monotonic()
            with anyio.fail_after(60):
                await writer.write("x" * 150_000)
            took = time.monotonic() - started
            tasks.cancel_scope.cancel()
    finally:
        stop.set()
        writer.close()
        os.close(write_end)
        with contextlib.suppress(OSError):
            while os.read(read_end, 65536):
                pass
        for thread in threads:
            thread.join(5)
        os.close(read_end)
    assert took > 0.5  # the write outlasted at least one of the reader's pauses ...
    assert max(gaps) < 0.4  # ... and the loop ran throughout: a write blocked in the kernel would show as a gap
