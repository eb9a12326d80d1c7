"""The bounded parser: what a request head must look like, and how reasons are read."""

from __future__ import annotations

import json

import pytest

from armwarden.stopchannel.wire import (
    HttpRefusal,
    bearer_token,
    find_head_end,
    parse_head,
    parse_reason,
    render_response,
)


def test_the_head_ends_at_the_first_blank_line() -> None:
    assert find_head_end(b"POST /estop HTTP/1.1\r\nA: b\r\n\r\nbody") == len(b"POST /estop HTTP/1.1\r\nA: b\r\n\r\n")
    assert find_head_end(b"POST /estop HTTP/1.1\nA: b\n\n") is not None
    assert find_head_end(b"POST /estop HTTP/1.1\r\nA: b\r\n") is None


def test_a_head_terminator_beyond_the_size_limit_is_not_found() -> None:
    assert find_head_end(b"POST /estop HTTP/1.1\r\nX: " + b"x" * 5000 + b"\r\n\r\n") is None


def test_a_valid_head_yields_token_length_and_type() -> None:
    head = parse_head(
        b"POST /estop HTTP/1.1\r\nHost: x\r\nauthorization:  Bearer abc \r\n"
        b"Content-Length: 12\r\nContent-Type: application/json; charset=utf-8\r\n\r\n"
    )

    assert (head.authorization, head.content_length, head.content_type) == ("Bearer abc", 12, "application/json")


def test_no_content_length_means_no_body() -> None:
    assert parse_head(b"POST /estop HTTP/1.0\r\n\r\n").content_length == 0


@pytest.mark.parametrize(
    ("head", "status"),
    [
        (b"GET /estop HTTP/1.1\r\n\r\n", 405),
        (b"POST /status HTTP/1.1\r\n\r\n", 404),
        (b"POST /estop?x=1 HTTP/1.1\r\n\r\n", 404),
        (b"POST /estop HTTP/1.1\r\n Folded: header\r\n\r\n", 400),
        (b"POST /estop HTTP/1.1\r\nContent-Length: 1e3\r\n\r\n", 400),
        (b"POST /estop HTTP/1.1\r\nContent-Length: 99999999999999\r\n\r\n", 400),
        (b"POST /estop HTTP/1.1\r\nContent-Length: 1025\r\n\r\n", 413),
        (b"POST /estop HTTP/1.1\r\nAuthorization: Bearer a\r\nAuthorization: Bearer b\r\n\r\n", 400),
        (b"POST /estop HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n", 501),
        (b"\xff\xfe /estop HTTP/1.1\r\n\r\n", 400),
    ],
)
def test_anything_but_a_plain_post_to_estop_is_refused(head: bytes, status: int) -> None:
    with pytest.raises(HttpRefusal) as refused:
        parse_head(head)

    assert refused.value.status == status


@pytest.mark.parametrize("authorization", [None, "", "Bearer", "Bearer   ", "Basic abc", "Token abc"])
def test_only_a_bearer_credential_carries_a_token(authorization: str | None) -> None:
    with pytest.raises(HttpRefusal) as refused:
        bearer_token(authorization)

    assert refused.value.status == 401


def test_the_bearer_scheme_is_case_insensitive() -> None:
    assert bearer_token("bearer aw_x") == "aw_x"


def test_a_json_reason_member_is_used() -> None:
    assert parse_reason(b'{"reason": "too\\nfast"}', "application/json") == "too fast"


def test_a_json_reason_of_any_type_is_shown() -> None:
    assert parse_reason(b'{"reason": [1, 2]}', "application/json") == "[1, 2]"


def test_invalid_json_is_taken_as_text() -> None:
    assert parse_reason(b'{"reason": ', "application/json") == '{"reason":'


def test_plain_text_is_flattened_and_truncated() -> None:
    reason = parse_reason(b"line one\r\nline two\x00 " + b"x" * 500, "text/plain")

    assert reason.startswith("line one line two x")
    assert len(reason) == 200 and reason.endswith("…")


def test_invalid_utf8_never_refuses_the_stop() -> None:
    assert parse_reason(b"\xff\xfe stop", "") == "�� stop"


def test_an_empty_body_has_no_reason() -> None:
    assert parse_reason(b"", "application/json") == ""


def test_answers_close_the_connection_and_carry_json() -> None:
    answer = render_response(405, {"error": "POST only"}, (("Allow", "POST"),))
    head, body = answer.split(b"\r\n\r\n", 1)

    assert head.startswith(b"HTTP/1.1 405 Method Not Allowed\r\n")
    assert b"\r\nConnection: close" in head and b"\r\nAllow: POST" in head
    assert json.loads(body) == {"error": "POST only"}
    assert f"Content-Length: {len(body)}".encode() in head
