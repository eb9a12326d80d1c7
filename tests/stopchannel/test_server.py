"""The stop channel as a client sees it: who may stop, what is refused, and the lifecycle."""

from __future__ import annotations

import http.client
import json
import socket
import threading
from pathlib import Path

import pytest

from armwarden.core.errors import ConfigurationError
from armwarden.stopchannel import StopChannel, token_store_authenticator
from armwarden.transport.tokens import TokenStore

from .conftest import (
    NETWORK_TIMEOUT_S,
    OBSERVER_TOKEN,
    TOKENS,
    Events,
    Latch,
    exchange,
    post,
    status_of,
)


# ---------------------------------------------------------------------------------------------- stopping
def test_a_plain_http_request_latches_and_answers_the_event_number(channel: StopChannel, latch: Latch) -> None:
    status, headers, answer = post(channel.port, b"gripper slipping", headers={"Content-Type": "text/plain"})

    assert status == 200
    assert answer["estopped"] is True and answer["event"] == 1
    assert answer["stop_issued_ms"] >= 0
    assert headers["connection"] == "close"
    assert latch.calls == [("gripper slipping", "alice")]


def test_an_observer_token_is_enough(channel: StopChannel, latch: Latch) -> None:
    status, _, _ = post(channel.port, token=OBSERVER_TOKEN)

    assert status == 200
    assert latch.calls == [("", "watcher")]


def test_a_json_reason_is_flattened_to_one_line(channel: StopChannel, latch: Latch) -> None:
    body = json.dumps({"reason": "arm\nhit\tthe table"}).encode()

    post(channel.port, body, headers={"Content-Type": "application/json"})

    assert latch.calls == [("arm hit the table", "alice")]


def test_a_body_of_the_maximum_size_is_accepted(channel: StopChannel, latch: Latch) -> None:
    status, _, _ = post(channel.port, b"r" * 1024)

    assert status == 200
    assert len(latch.calls[0][0]) <= 200


def test_each_stop_gets_the_latch_event_number(channel: StopChannel) -> None:
    events = [post(channel.port)[2]["event"] for _ in range(3)]

    assert events == [1, 2, 3]


def test_tokens_from_a_token_store_authenticate_any_role(tmp_path: Path, make_channel, latch: Latch) -> None:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", name="night-shift")
    channel = make_channel(authenticate=token_store_authenticator(TokenStore.load(path)))

    assert post(channel.port, token=token)[0] == 200
    TokenStore.revoke(path, "night-shift")
    assert post(channel.port, token=token)[0] == 401
    assert latch.calls == [("", "night-shift")]


# ---------------------------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("token", [None, "", "aw_wrong", OBSERVER_TOKEN + "x"])
def test_a_missing_or_wrong_token_is_refused_without_stopping(channel: StopChannel, latch: Latch, token) -> None:
    status, headers, answer = post(channel.port, token=token)

    assert status == 401
    assert headers["www-authenticate"].startswith("Bearer")
    assert "token" in answer["error"]
    assert latch.calls == []


def test_a_basic_credential_is_refused(channel: StopChannel, latch: Latch) -> None:
    status, _, _ = post(channel.port, token=None, headers={"Authorization": "Basic YWxpY2U6cHc="})

    assert status == 401
    assert latch.calls == []


def test_an_authenticator_that_raises_refuses_the_request(make_channel, latch: Latch) -> None:
    def broken(token: str) -> str | None:
        raise RuntimeError("token file vanished")

    channel = make_channel(authenticate=broken)
    status, _, answer = post(channel.port)

    assert status == 500
    assert "no stop was issued" in answer["error"]
    assert latch.calls == []


def test_oversized_headers_are_refused_with_413(channel: StopChannel, latch: Latch) -> None:
    status, _, _ = post(channel.port, headers={"X-Padding": "p" * 5000})

    assert status == 413
    assert latch.calls == []


def test_an_oversized_body_is_refused_with_413(channel: StopChannel, latch: Latch) -> None:
    status, _, answer = post(channel.port, b"r" * 1025)

    assert status == 413
    assert "1024" in answer["error"]
    assert latch.calls == []


def test_a_chunked_body_is_refused(channel: StopChannel, latch: Latch) -> None:
    request = (
        b"POST /estop HTTP/1.1\r\nAuthorization: Bearer aw_operator-token\r\n"
        b"Transfer-Encoding: chunked\r\n\r\n3\r\nabc\r\n0\r\n\r\n"
    )

    assert status_of(exchange(channel.port, request)) == 501
    assert latch.calls == []


@pytest.mark.parametrize(
    "request_bytes",
    [
        b"GARBAGE\r\n\r\n",
        b"POST /estop\r\n\r\n",
        b"POST /estop HTTP/9.9\r\n\r\n",
        b"POST  /estop HTTP/1.1\r\n\r\n",
        b"POST /estop HTTP/1.1\r\nno colon here\r\n\r\n",
        b"POST /estop HTTP/1.1\r\nContent-Length: -1\r\n\r\n",
        b"POST /estop HTTP/1.1\r\nContent-Length: 1\r\nContent-Length: 1\r\n\r\nx",
    ],
)
def test_a_malformed_request_is_refused_with_400(channel: StopChannel, latch: Latch, request_bytes: bytes) -> None:
    assert status_of(exchange(channel.port, request_bytes)) == 400
    assert latch.calls == []


def test_a_wrong_method_is_refused_with_405(channel: StopChannel, latch: Latch) -> None:
    status, headers, _ = post(channel.port, method="GET")

    assert status == 405
    assert headers["allow"] == "POST"
    assert latch.calls == []


def test_a_wrong_path_is_refused_with_404(channel: StopChannel, latch: Latch) -> None:
    status, _, _ = post(channel.port, path="/estop/../reset")

    assert status == 404
    assert latch.calls == []


def test_a_request_that_does_not_arrive_in_time_gets_408(make_channel, latch: Latch) -> None:
    channel = make_channel(request_timeout_s=0.2)
    with socket.create_connection(("127.0.0.1", channel.port), timeout=NETWORK_TIMEOUT_S) as sock:
        sock.sendall(b"POST /estop HTTP/1.1\r\n")
        answer = sock.recv(4096)

    assert status_of(answer) == 408
    assert latch.calls == []


# ---------------------------------------------------------------------------------------------- failures
def test_a_failing_latch_answers_500_with_its_message(make_channel, events: Events) -> None:
    def failing_latch(reason: str, principal: str) -> int:
        raise RuntimeError("backend stop timed out")

    channel = make_channel(latch_and_stop=failing_latch)
    status, _, answer = post(channel.port)

    assert status == 500
    assert "backend stop timed out" in answer["error"]
    assert "may NOT have been issued" in answer["error"]
    assert events.arrived.wait(NETWORK_TIMEOUT_S)
    assert events.received[0].event is None and "backend stop timed out" in events.received[0].error


def test_on_event_runs_after_the_reply_was_sent(make_channel) -> None:
    replied = threading.Event()
    seen_after_reply: list[bool] = []
    done = threading.Event()

    def on_event(stop) -> None:
        seen_after_reply.append(replied.wait(NETWORK_TIMEOUT_S))  # would block the reply if run before it
        done.set()

    channel = make_channel(on_event=on_event)
    status, _, _ = post(channel.port, b"audit me")
    replied.set()

    assert status == 200
    assert done.wait(NETWORK_TIMEOUT_S)
    assert seen_after_reply == [True]


def test_on_event_receives_who_why_and_the_event(channel: StopChannel, events: Events) -> None:
    post(channel.port, b"too close to the operator")

    assert events.arrived.wait(NETWORK_TIMEOUT_S)
    stop = events.received[0]
    assert (stop.principal, stop.reason, stop.event, stop.error) == ("alice", "too close to the operator", 1, None)
    assert stop.peer.startswith("127.0.0.1:")


def test_a_failing_on_event_does_not_affect_the_reply_or_later_stops(make_channel, latch: Latch) -> None:
    def broken_audit(stop) -> None:
        raise OSError("audit disk full")

    channel = make_channel(on_event=broken_audit)

    assert post(channel.port)[0] == 200
    assert post(channel.port)[0] == 200
    assert len(latch.calls) == 2


# ---------------------------------------------------------------------------------------------- lifecycle
def test_close_twice_is_safe_and_stops_listening(channel: StopChannel) -> None:
    port = channel.port
    channel.close()
    channel.close()

    assert not channel.is_serving
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=NETWORK_TIMEOUT_S)


def test_close_before_start_is_safe_and_start_after_close_is_refused(latch: Latch) -> None:
    channel = StopChannel(authenticate=TOKENS.get, latch_and_stop=latch)
    channel.close()

    with pytest.raises(RuntimeError):
        channel.start()


def test_the_context_manager_starts_and_closes(latch: Latch) -> None:
    with StopChannel(authenticate=TOKENS.get, latch_and_stop=latch) as channel:
        assert channel.is_serving
        assert post(channel.port)[0] == 200
    assert not channel.is_serving


@pytest.mark.parametrize("host", ["0.0.0.0", "::"])
def test_a_non_loopback_address_is_refused_unless_allowed(latch: Latch, host: str) -> None:
    channel = StopChannel(authenticate=TOKENS.get, latch_and_stop=latch, host=host)

    with pytest.raises(ConfigurationError, match="non-loopback"):
        channel.start()
    channel.close()


def test_a_port_in_use_is_a_clear_error_before_serving(channel: StopChannel, latch: Latch) -> None:
    second = StopChannel(authenticate=TOKENS.get, latch_and_stop=latch, port=channel.port)

    with pytest.raises(ConfigurationError, match=f"cannot listen on 127.0.0.1:{channel.port}"):
        second.start()
    assert not second.is_serving
    second.close()


def test_the_url_names_the_bound_port(channel: StopChannel) -> None:
    assert channel.url == f"http://127.0.0.1:{channel.port}/estop"
    assert channel.port != 0


def test_a_plain_http_client_is_told_to_close(channel: StopChannel) -> None:
    connection = http.client.HTTPConnection("127.0.0.1", channel.port, timeout=NETWORK_TIMEOUT_S)
    connection.request("POST", "/estop", headers={"Authorization": "Bearer aw_operator-token"})
    response = connection.getresponse()
    response.read()

    assert response.will_close
    connection.close()
