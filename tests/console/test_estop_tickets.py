"""Console sessions' E-STOP tickets: what the stop channel checks on its own thread."""

from __future__ import annotations

from pathlib import Path

from armwarden.console import SessionStore
from armwarden.transport.tokens import TokenStore


def store_with(tmp_path: Path) -> tuple[SessionStore, str, Path]:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", name="bob")
    return SessionStore(TokenStore.load(path)), token, path


def test_a_sessions_ticket_names_its_token(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)

    assert session is not None
    assert sessions.principal_for_ticket(session.estop_ticket) == "bob"


def test_the_ticket_reveals_neither_the_session_id_nor_the_csrf_token(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)

    assert session is not None
    assert session.estop_ticket not in (session.session_id, session.csrf)
    assert session.session_id not in session.estop_ticket


def test_two_sessions_have_different_tickets(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    first, second = sessions.sign_in(token), sessions.sign_in(token)

    assert first is not None and second is not None
    assert first.estop_ticket != second.estop_ticket


def test_signing_out_ends_the_ticket(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert session is not None

    sessions.sign_out(session.session_id)

    assert sessions.principal_for_ticket(session.estop_ticket) is None


def test_revoking_the_token_ends_the_ticket(tmp_path: Path) -> None:
    sessions, token, path = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert session is not None

    TokenStore.revoke(path, "bob")

    assert sessions.principal_for_ticket(session.estop_ticket) is None


def test_an_expired_session_ends_the_ticket(tmp_path: Path) -> None:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", name="bob")
    now = [0.0]
    sessions = SessionStore(TokenStore.load(path), clock=lambda: now[0], ttl_s=10.0)
    session = sessions.sign_in(token)
    assert session is not None

    now[0] = 10.0

    assert sessions.principal_for_ticket(session.estop_ticket) is None


def test_unknown_tickets_and_non_strings_are_nobody(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert session is not None

    assert [sessions.principal_for_ticket(t) for t in ("", "x", session.session_id, None, 7)] == [None] * 5
