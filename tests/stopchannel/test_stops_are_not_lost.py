"""Ways a real stop could be lost on the channel, each closed: idle connections crowding it, a
token file that broke, a connection the channel dropped unanswered."""

from __future__ import annotations

import socket
import struct
import threading
from pathlib import Path

from armwarden.stopchannel import ChannelRefusal, send_estop, token_store_authenticator
from armwarden.transport.tokens import TokenStore
from tests.stopchannel.conftest import NETWORK_TIMEOUT_S, OPERATOR_TOKEN, post


def test_a_stop_sent_while_idle_connections_pour_in_is_served(make_channel, latch) -> None:
    channel = make_channel(max_connections=4)
    idle: list[socket.socket] = []
    pouring = threading.Event()

    def pour() -> None:
        while not pouring.is_set() and len(idle) < 200:
            idle.append(socket.create_connection(("127.0.0.1", channel.port), timeout=NETWORK_TIMEOUT_S))

    flood = threading.Thread(target=pour)
    flood.start()
    try:
        answer = send_estop(f"http://127.0.0.1:{channel.port}/estop", OPERATOR_TOKEN, "crowded")
    finally:
        pouring.set()
        flood.join()
        for sock in idle:
            sock.close()
    assert answer["estopped"] is True and len(latch.calls) == 1


def test_a_silent_connection_holding_the_only_slot_does_not_keep_a_stop_out(make_channel, latch) -> None:
    channel = make_channel(max_connections=1)
    # the stop's connection evicts it (the oldest idle one goes first)
    squatter = socket.create_connection(("127.0.0.1", channel.port), timeout=NETWORK_TIMEOUT_S)
    try:
        answer = send_estop(f"http://127.0.0.1:{channel.port}/estop", OPERATOR_TOKEN)
    finally:
        squatter.close()
    assert answer["estopped"] is True and len(latch.calls) == 1


def test_a_valid_token_still_stops_after_the_token_file_becomes_unusable(tmp_path: Path, make_channel, latch) -> None:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", "watcher")
    channel = make_channel(authenticate=token_store_authenticator(TokenStore.load(path)))
    path.unlink()  # or a bad edit, or chmod g+w: the file is now unusable
    status, _, answer = post(channel.port, token=token)
    assert status == 200, answer
    assert len(latch.calls) == 1


def test_a_token_revoked_in_a_usable_file_no_longer_stops(tmp_path: Path, make_channel, latch) -> None:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", "watcher")
    TokenStore.add(path, "operator", "keeper")
    channel = make_channel(authenticate=token_store_authenticator(TokenStore.load(path)))
    assert TokenStore.revoke(path, "watcher")
    status, _, _ = post(channel.port, token=token)
    assert status == 401 and latch.calls == []


def test_a_connection_dropped_unanswered_is_retried_by_send_estop() -> None:
    """The channel drops idle connections when a flood fills it; a client whose connection was
    dropped before its answer tries again (a stop is safe to repeat)."""
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    attempts: list[int] = []

    def serve() -> None:
        for attempt in range(2):
            connection, _ = listener.accept()
            with connection:
                connection.recv(65536)
                attempts.append(attempt)
                if attempt == 0:  # dropped unanswered, with a reset
                    connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                    continue
                body = b'{"estopped": true, "event": 7}'
                connection.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nConnection: close\r\n"
                                   + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)

    server = threading.Thread(target=serve)
    server.start()
    try:
        answer = send_estop(f"http://127.0.0.1:{port}/estop", OPERATOR_TOKEN, timeout_s=NETWORK_TIMEOUT_S)
    finally:
        server.join(NETWORK_TIMEOUT_S)
        listener.close()
    assert answer == {"estopped": True, "event": 7}
    assert attempts == [0, 1]


def test_refused_requests_are_reported_at_most_once_per_host_and_second(make_channel, latch) -> None:
    reported: list[ChannelRefusal] = []
    channel = make_channel(on_refused=reported.append)
    for _ in range(5):
        status, _, _ = post(channel.port, token="aw_wrong")
        assert status == 401
    assert latch.calls == []
    assert len(reported) == 1 and reported[0].status == 401 and reported[0].peer.startswith("127.0.0.1:")
    assert "unknown bearer token" in reported[0].message
