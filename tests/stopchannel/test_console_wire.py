"""The console E-STOP's part of the bounded parser: its head, its one-field form, its HTML answer,
and who may stop without a ticket."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from armwarden.stopchannel.console_door import CONSOLE_UNSIGNED_PRINCIPAL, ConsoleDoor, authorise_console_estop
from armwarden.stopchannel.wire import (
    CONSOLE_ESTOP_PATH,
    FORM_CONTENT_TYPE,
    MAX_BODY_BYTES,
    HttpRefusal,
    parse_console_form,
    parse_head,
    render_html_response,
)

TICKET = "q3S0dXj9nJm3Zz-E1_7wYxkXgq2sMqf8aH6bKz0P3nI"
ORIGIN = "http://127.0.0.1:8765"


def door(allow_loopback_without_ticket: bool = True) -> ConsoleDoor:
    return ConsoleDoor(check_ticket={TICKET: "alice"}.get, latch_and_stop=lambda reason, who: 1,
                       allowed_origins=frozenset({ORIGIN}), allow_loopback_without_ticket=allow_loopback_without_ticket)


def refusal_of(call: object, *args: object) -> HttpRefusal:
    with pytest.raises(HttpRefusal) as refused:
        call(*args)  # type: ignore[operator]
    return refused.value


# ------------------------------------------------------------------ head
def test_a_console_head_yields_its_path_and_origin() -> None:
    head = parse_head(
        b"POST /console-estop HTTP/1.1\r\nHost: 127.0.0.1:9\r\nOrigin: " + ORIGIN.encode() + b"\r\n"
        b"Content-Type: application/x-www-form-urlencoded;charset=UTF-8\r\nContent-Length: 10\r\n\r\n"
    )

    assert (head.path, head.origin, head.content_type) == (CONSOLE_ESTOP_PATH, ORIGIN, FORM_CONTENT_TYPE)


def test_a_head_without_origin_has_none() -> None:
    assert parse_head(b"POST /console-estop HTTP/1.1\r\n\r\n").origin is None


@pytest.mark.parametrize(
    ("head", "status"),
    [
        (b"GET /console-estop HTTP/1.1\r\n\r\n", 405),
        (b"POST /console-estop?ticket=x HTTP/1.1\r\n\r\n", 404),
        (b"POST /console-estop HTTP/1.1\r\nOrigin: http://a\r\nOrigin: http://b\r\n\r\n", 400),
        (b"POST /console-estop HTTP/1.1\r\nContent-Length: 1025\r\n\r\n", 413),
        (b"POST /console-estop HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n", 501),
    ],
)
def test_anything_but_a_plain_console_post_is_refused(head: bytes, status: int) -> None:
    assert refusal_of(parse_head, head).status == status


# ------------------------------------------------------------------ form
def test_the_form_carries_the_ticket() -> None:
    assert parse_console_form(f"ticket={TICKET}".encode(), FORM_CONTENT_TYPE) == TICKET


@pytest.mark.parametrize("body", [b"", b"ticket="])
def test_an_empty_form_carries_no_ticket(body: bytes) -> None:
    assert parse_console_form(body, FORM_CONTENT_TYPE) is None


@pytest.mark.parametrize(
    "body",
    [
        b"ticket=a&ticket=b",  # a second ticket
        b"csrf=x",  # another field
        b"ticket=a&csrf=x",
        b"ticket",  # no '='
        b"ticket=a=b",
        b"ticket=%3Cscript%3E",  # not a URL-safe token once decoded
        b"ticket=" + b"a" * 129,  # too long
        b"ticket=\xff",  # not ASCII
        b"&",
    ],
)
def test_a_malformed_form_is_refused(body: bytes) -> None:
    assert refusal_of(parse_console_form, body, FORM_CONTENT_TYPE).status == 400


@pytest.mark.parametrize("content_type", ["application/json", "text/plain", "multipart/form-data", ""])
def test_a_body_that_is_not_a_urlencoded_form_is_refused(content_type: str) -> None:
    assert refusal_of(parse_console_form, b"ticket=abc", content_type).status == 415


@given(st.binary(max_size=MAX_BODY_BYTES))
def test_any_body_yields_a_ticket_none_or_a_refusal(body: bytes) -> None:
    outcome: str | int | None
    try:
        outcome = parse_console_form(body, FORM_CONTENT_TYPE)
    except HttpRefusal as refusal:
        outcome = refusal.status

    assert outcome in (None, 400) or (isinstance(outcome, str) and 0 < len(outcome) <= 128 and outcome.isascii())


# ------------------------------------------------------------------ who may stop
def test_a_known_ticket_is_its_sessions_token_name() -> None:
    assert authorise_console_estop(door(), TICKET, "127.0.0.1") == "alice"


def test_a_known_ticket_works_from_another_machine() -> None:
    assert authorise_console_estop(door(), TICKET, "192.0.2.7") == "alice"


@pytest.mark.parametrize("peer", ["192.0.2.7", "::ffff:192.0.2.7"])
def test_a_wrong_ticket_from_another_machine_is_refused(peer: str) -> None:
    assert refusal_of(authorise_console_estop, door(), TICKET[:-1] + "x", peer).status == 401


def test_a_wrong_ticket_from_loopback_is_the_unsigned_console() -> None:
    assert authorise_console_estop(door(), TICKET[:-1] + "x", "127.0.0.1") == CONSOLE_UNSIGNED_PRINCIPAL


@pytest.mark.parametrize("peer", ["127.0.0.1", "127.3.2.1", "::1", "::ffff:127.0.0.1"])
def test_no_ticket_from_loopback_is_the_unsigned_console(peer: str) -> None:
    assert authorise_console_estop(door(), None, peer) == CONSOLE_UNSIGNED_PRINCIPAL


@pytest.mark.parametrize("peer", ["192.0.2.7", "::ffff:192.0.2.7", "10.0.0.1", "not-an-address"])
def test_no_ticket_from_another_machine_is_refused(peer: str) -> None:
    assert refusal_of(authorise_console_estop, door(), None, peer).status == 401


def test_no_ticket_is_refused_when_the_console_needs_sign_in() -> None:
    assert refusal_of(authorise_console_estop, door(allow_loopback_without_ticket=False), None, "127.0.0.1").status == 401


# ------------------------------------------------------------------ answer
def test_the_html_answer_escapes_and_links_back() -> None:
    answer = render_html_response(401, "refused: <b>", "http://127.0.0.1:8765/console/safety?a=1&b=2")
    head, body = answer.split(b"\r\n\r\n", 1)

    assert head.startswith(b"HTTP/1.1 401 Unauthorized\r\n") and b"Connection: close" in head
    assert b"Content-Type: text/html" in head and b"default-src 'none'" in head
    assert b"refused: &lt;b&gt;" in body
    assert b'href="http://127.0.0.1:8765/console/safety?a=1&amp;b=2"' in body
    assert f"Content-Length: {len(body)}".encode() in head
