"""Slow, silent and half-open connections can never keep a real stop out."""

from __future__ import annotations

import collections
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress

import pytest

from armwarden.stopchannel import StopChannel

from .conftest import NETWORK_TIMEOUT_S, Latch, post

SLOW_REQUEST = b"POST /estop HTTP/1.1\r\nAuthorization: Bearer aw_nobody\r\nX-Slow: " + b"s" * 4096


@contextmanager
def slow_connections(port: int, count: int) -> Iterator[list[socket.socket]]:
    """`count` connections: half send nothing, half drip a request one byte at a time."""
    sockets = [socket.create_connection(("127.0.0.1", port), timeout=NETWORK_TIMEOUT_S) for _ in range(count)]
    stop_dripping, mid_request = threading.Event(), threading.Event()

    def drip() -> None:
        position = 0
        while not stop_dripping.is_set() and position < len(SLOW_REQUEST):
            for sock in sockets[::2]:
                with suppress(OSError):  # evicted or timed out by the channel: that is its job
                    sock.send(SLOW_REQUEST[position : position + 1])
            position += 1
            if position == 20:
                mid_request.set()
            stop_dripping.wait(0.01)

    dripper = threading.Thread(target=drip, daemon=True)
    dripper.start()
    assert mid_request.wait(NETWORK_TIMEOUT_S)  # the slow requests are under way
    try:
        yield sockets
    finally:
        stop_dripping.set()
        dripper.join()
        for sock in sockets:
            sock.close()


@pytest.mark.timeout(60)
@pytest.mark.parametrize("slow_count", [50, 250])
def test_a_stop_is_served_while_slow_connections_are_held_open(make_channel, latch: Latch, slow_count: int) -> None:
    # a long request deadline: only the design (one loop, eviction) may let the stop through, not timeouts
    channel: StopChannel = make_channel(request_timeout_s=60.0)

    with slow_connections(channel.port, slow_count):
        status, _, answer = post(channel.port, b"real stop")

    assert status == 200 and answer["event"] == 1
    assert latch.calls == [("real stop", "alice")]


@pytest.mark.timeout(60)
def test_a_small_connection_cap_evicts_the_oldest_silent_connection(make_channel, latch: Latch) -> None:
    channel: StopChannel = make_channel(request_timeout_s=60.0, max_connections=4)

    with slow_connections(channel.port, 20):
        status, _, _ = post(channel.port)
        status_again, _, _ = post(channel.port)

    assert (status, status_again) == (200, 200)
    assert len(latch.calls) == 2


@pytest.mark.timeout(60)
def test_connections_that_close_without_a_request_leave_the_channel_serving(channel: StopChannel, latch: Latch) -> None:
    for _ in range(100):
        socket.create_connection(("127.0.0.1", channel.port), timeout=NETWORK_TIMEOUT_S).close()

    assert post(channel.port)[0] == 200
    assert channel.is_serving


@pytest.mark.timeout(60)
def test_stops_are_served_while_new_silent_connections_keep_arriving(make_channel, latch: Latch) -> None:
    channel: StopChannel = make_channel(request_timeout_s=60.0, max_connections=16)
    flooding = threading.Event()
    stop_flooding = threading.Event()

    def flood() -> None:
        held: collections.deque[socket.socket] = collections.deque()
        while not stop_flooding.is_set():
            with suppress(OSError):
                held.append(socket.create_connection(("127.0.0.1", channel.port), timeout=NETWORK_TIMEOUT_S))
            if len(held) > 300:
                held.popleft().close()
            if len(held) == 100:
                flooding.set()
        for sock in held:
            sock.close()

    flooder = threading.Thread(target=flood, daemon=True)
    flooder.start()
    try:
        assert flooding.wait(NETWORK_TIMEOUT_S)
        statuses = [post(channel.port)[0] for _ in range(5)]
    finally:
        stop_flooding.set()
        flooder.join()

    assert statuses == [200] * 5
    assert len(latch.calls) == 5
