"""Fixtures for the stop channel: a recording latch, a started channel, and small clients."""

from __future__ import annotations

import http.client
import json
import socket
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

from armwarden.stopchannel import ChannelStop, StopChannel

OBSERVER_TOKEN = "aw_observer-token"
OPERATOR_TOKEN = "aw_operator-token"
TOKENS = {OBSERVER_TOKEN: "watcher", OPERATOR_TOKEN: "alice"}
NETWORK_TIMEOUT_S = 10.0  # generous: only there so a broken channel fails the test instead of hanging it


@dataclass
class Latch:
    """A thread-safe stand-in for the daemon's latch_and_stop: records calls, numbers events."""

    calls: list[tuple[str, str]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __call__(self, reason: str, principal: str) -> int:
        with self.lock:
            self.calls.append((reason, principal))
            return len(self.calls)


@dataclass
class Events:
    """Collects the channel's on_event reports."""

    received: list[ChannelStop] = field(default_factory=list)
    arrived: threading.Event = field(default_factory=threading.Event)

    def __call__(self, stop: ChannelStop) -> None:
        self.received.append(stop)
        self.arrived.set()


@pytest.fixture
def latch() -> Latch:
    return Latch()


@pytest.fixture
def events() -> Events:
    return Events()


@pytest.fixture
def make_channel(latch: Latch, events: Events) -> Iterator[Callable[..., StopChannel]]:
    """Start channels on 127.0.0.1 with the test tokens; every one is closed at teardown."""
    started: list[StopChannel] = []

    def make(**overrides: Any) -> StopChannel:
        options: dict[str, Any] = {"authenticate": TOKENS.get, "latch_and_stop": latch, "on_event": events}
        options.update(overrides)
        channel = StopChannel(**options)
        started.append(channel)
        return channel.start()

    yield make
    for channel in started:
        channel.close()


@pytest.fixture
def channel(make_channel: Callable[..., StopChannel]) -> StopChannel:
    return make_channel()


def post(
    port: int,
    body: bytes = b"",
    *,
    token: str | None = OPERATOR_TOKEN,
    path: str = "/estop",
    method: str = "POST",
    headers: dict[str, str] | None = None,
) -> tuple[int, dict[str, str], dict[str, Any]]:
    """One request with http.client: (status, lower-cased headers, decoded JSON answer)."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=NETWORK_TIMEOUT_S)
    sent = dict(headers or {})
    if token is not None:
        sent["Authorization"] = f"Bearer {token}"
    try:
        connection.request(method, path, body=body, headers=sent)
        response = connection.getresponse()
        answer = json.loads(response.read() or b"{}")
        return response.status, {k.lower(): v for k, v in response.getheaders()}, answer
    finally:
        connection.close()


def exchange(port: int, data: bytes) -> bytes:
    """Send raw `data`, half-close, and return everything the channel answers until it closes."""
    with socket.create_connection(("127.0.0.1", port), timeout=NETWORK_TIMEOUT_S) as sock:
        try:
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass  # the channel may already have answered and closed (e.g. 413 on an endless head)
        chunks = []
        while True:
            try:
                chunk = sock.recv(65536)
            except ConnectionResetError:
                break
            if not chunk:
                break
            chunks.append(chunk)
    return b"".join(chunks)


def status_of(answer: bytes) -> int | None:
    """The status code of a raw HTTP answer, or None when the channel closed without one."""
    if not answer:
        return None
    return int(answer.split(b" ", 2)[1])
