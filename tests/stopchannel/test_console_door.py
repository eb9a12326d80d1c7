"""The channel's door for the operator console: ``POST /console-estop`` as a browser sends it
(a form, no preflight), answered with a tiny HTML page; foreign origins and bad tickets refused."""

from __future__ import annotations

import http.client
from collections.abc import Callable

from armwarden.stopchannel import ConsoleDoor, StopChannel
from armwarden.stopchannel.console_door import CONSOLE_UNSIGNED_PRINCIPAL

from .conftest import NETWORK_TIMEOUT_S, OPERATOR_TOKEN, Events, Latch, post

TICKET = "9bW6c0aFQm1xT3vJkLr2sYpZq8dN4eHu7gC5iO0tA_-"
ORIGIN = "http://127.0.0.1:8765"
BACK = "http://127.0.0.1:8765/console/safety"
FORM = {"Content-Type": "application/x-www-form-urlencoded"}


def door(latch: Latch, **overrides: object) -> ConsoleDoor:
    options: dict[str, object] = {"check_ticket": {TICKET: "bob"}.get, "latch_and_stop": latch,
                                  "allowed_origins": frozenset({ORIGIN}), "back_url": BACK}
    options.update(overrides)
    return ConsoleDoor(**options)  # type: ignore[arg-type]


def press(port: int, body: bytes = b"", headers: dict[str, str] | None = None) -> tuple[int, str]:
    """What the console page's form sends: (status, HTML answer)."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=NETWORK_TIMEOUT_S)
    try:
        connection.request("POST", "/console-estop", body=body, headers={**FORM, **(headers or {})})
        response = connection.getresponse()
        assert response.getheader("Content-Type", "").startswith("text/html")
        return response.status, response.read().decode()
    finally:
        connection.close()


def test_a_signed_in_page_stops_with_its_ticket(make_channel: Callable[..., StopChannel], events: Events) -> None:
    console_latch = Latch()
    channel = make_channel(console=door(console_latch))

    status, page = press(channel.port, f"ticket={TICKET}".encode(), {"Origin": ORIGIN})

    assert status == 200
    assert "E-STOP latched: event #1" in page and f'href="{BACK}"' in page
    assert console_latch.calls == [("operator console E-STOP", "bob")]
    assert events.arrived.wait(NETWORK_TIMEOUT_S)
    assert events.received[0].principal == "bob" and events.received[0].peer.startswith("console via stop channel")


def test_no_ticket_from_loopback_stops_as_the_unsigned_console(make_channel: Callable[..., StopChannel]) -> None:
    console_latch = Latch()
    channel = make_channel(console=door(console_latch))

    status, _ = press(channel.port)

    assert status == 200
    assert console_latch.calls == [("operator console E-STOP", CONSOLE_UNSIGNED_PRINCIPAL)]


def test_a_stale_ticket_from_loopback_stops_as_the_unsigned_console(make_channel: Callable[..., StopChannel]) -> None:
    """A ticket that names nobody (unknown, or its token revoked) stops wherever a page without
    a ticket would: here, from this machine."""
    console_latch = Latch()
    channel = make_channel(console=door(console_latch))

    status, _ = press(channel.port, b"ticket=not-the-ticket", {"Origin": ORIGIN})

    assert status == 200
    assert console_latch.calls == [("operator console E-STOP", CONSOLE_UNSIGNED_PRINCIPAL)]


def test_a_wrong_ticket_is_refused_and_nothing_stops_when_the_console_needs_sign_in(
        make_channel: Callable[..., StopChannel], latch: Latch) -> None:
    console_latch = Latch()
    channel = make_channel(console=door(console_latch, allow_loopback_without_ticket=False))

    status, page = press(channel.port, b"ticket=not-the-ticket", {"Origin": ORIGIN})

    assert status == 401 and "E-STOP refused" in page and "sign in again" in page
    assert console_latch.calls == [] and latch.calls == []


def test_no_ticket_is_refused_when_the_console_needs_sign_in(make_channel: Callable[..., StopChannel]) -> None:
    console_latch = Latch()
    channel = make_channel(console=door(console_latch, allow_loopback_without_ticket=False))

    status, _ = press(channel.port)

    assert status == 401
    assert console_latch.calls == []


def test_a_foreign_origin_is_refused(make_channel: Callable[..., StopChannel]) -> None:
    console_latch = Latch()
    channel = make_channel(console=door(console_latch))

    statuses = [press(channel.port, b"", {"Origin": origin})[0] for origin in ("http://evil.example", "null")]

    assert statuses == [403, 403]
    assert console_latch.calls == []


def test_a_bearer_token_does_not_open_the_console_door(make_channel: Callable[..., StopChannel]) -> None:
    console_latch = Latch()
    channel = make_channel(console=door(console_latch, allow_loopback_without_ticket=False))

    status, _ = press(channel.port, headers={"Authorization": f"Bearer {OPERATOR_TOKEN}"})

    assert status == 401
    assert console_latch.calls == []


def test_a_channel_without_a_console_has_no_door(channel: StopChannel, latch: Latch) -> None:
    status, _ = press(channel.port)

    assert status == 404
    assert latch.calls == []


def test_the_bearer_estop_still_works_beside_the_door(make_channel: Callable[..., StopChannel], latch: Latch) -> None:
    channel = make_channel(console=door(Latch()))

    status, _, answer = post(channel.port)

    assert status == 200 and answer["event"] == 1
    assert latch.calls == [("", "alice")]


def test_the_console_url_names_the_door(make_channel: Callable[..., StopChannel]) -> None:
    channel = make_channel(console=door(Latch()))

    assert channel.console_url == f"http://127.0.0.1:{channel.port}/console-estop"
