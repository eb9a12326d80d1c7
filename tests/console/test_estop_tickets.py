"""Console sessions' E-STOP tickets: what the stop channel checks on its own thread; and the
session table's room (per token, never taken from another token)."""

from __future__ import annotations

from pathlib import Path

from armwarden.console import SessionStore
from armwarden.console.sessions import Session, SignInRefused
from armwarden.transport.tokens import TokenStore


def store_with(tmp_path: Path) -> tuple[SessionStore, str, Path]:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", name="bob")
    return SessionStore(TokenStore.load(path)), token, path


def test_a_sessions_ticket_names_its_token(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)

    assert isinstance(session, Session)
    assert sessions.principal_for_ticket(session.estop_ticket) == "bob"


def test_the_ticket_reveals_neither_the_session_id_nor_the_csrf_token(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)

    assert isinstance(session, Session)
    assert session.estop_ticket not in (session.session_id, session.csrf)
    assert session.session_id not in session.estop_ticket


def test_two_sessions_have_different_tickets(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    first, second = sessions.sign_in(token), sessions.sign_in(token)

    assert isinstance(first, Session) and isinstance(second, Session)
    assert first.estop_ticket != second.estop_ticket


def test_a_signed_out_sessions_ticket_still_stops_as_an_ended_session(tmp_path: Path) -> None:
    """A tab still open after signing out in another one: its E-STOP must still stop."""
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert isinstance(session, Session)

    sessions.sign_out(session.session_id)

    assert sessions.lookup(session.session_id) is None
    assert sessions.principal_for_ticket(session.estop_ticket) == "bob (session ended)"


def test_revoking_the_token_ends_the_ticket(tmp_path: Path) -> None:
    sessions, token, path = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert isinstance(session, Session)

    TokenStore.revoke(path, "bob")

    assert sessions.principal_for_ticket(session.estop_ticket) is None


def test_an_expired_sessions_ticket_still_stops_as_an_ended_session(tmp_path: Path) -> None:
    path = tmp_path / "tokens.json"
    token = TokenStore.add(path, "observer", name="bob")
    now = [0.0]
    sessions = SessionStore(TokenStore.load(path), clock=lambda: now[0], ttl_s=10.0)
    session = sessions.sign_in(token)
    assert isinstance(session, Session)

    now[0] = 10.0

    assert sessions.lookup(session.session_id) is None
    assert sessions.principal_for_ticket(session.estop_ticket) == "bob (session ended)"


def test_a_revoked_tokens_ended_session_ticket_does_not_stop(tmp_path: Path) -> None:
    sessions, token, path = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert isinstance(session, Session)
    sessions.sign_out(session.session_id)

    TokenStore.revoke(path, "bob")

    assert sessions.principal_for_ticket(session.estop_ticket) is None


def test_a_tokens_sign_ins_over_its_limit_end_its_own_oldest_session(tmp_path: Path) -> None:
    _, token, path = store_with(tmp_path)
    sessions = SessionStore(TokenStore.load(path), max_sessions=4, max_per_principal=2)
    first, second, third = (sessions.sign_in(token) for _ in range(3))
    assert isinstance(first, Session) and isinstance(second, Session) and isinstance(third, Session)

    assert sessions.lookup(first.session_id) is None
    assert sessions.lookup(second.session_id) == second and sessions.lookup(third.session_id) == third


def test_a_full_table_refuses_a_sign_in_and_ends_no_other_tokens_session(tmp_path: Path) -> None:
    path = tmp_path / "tokens.json"
    tokens = [TokenStore.add(path, "observer", name=name) for name in ("bob", "carol", "dana")]
    sessions = SessionStore(TokenStore.load(path), max_sessions=2, max_per_principal=1)
    bob, carol = sessions.sign_in(tokens[0]), sessions.sign_in(tokens[1])
    assert isinstance(bob, Session) and isinstance(carol, Session)

    dana = sessions.sign_in(tokens[2])

    assert isinstance(dana, SignInRefused) and dana.reason == "full" and "sign out" in dana.message
    assert sessions.lookup(bob.session_id) == bob and sessions.lookup(carol.session_id) == carol


def test_an_expired_session_takes_no_room(tmp_path: Path) -> None:
    path = tmp_path / "tokens.json"
    tokens = [TokenStore.add(path, "observer", name=name) for name in ("bob", "carol")]
    now = [0.0]
    sessions = SessionStore(TokenStore.load(path), clock=lambda: now[0], ttl_s=10.0, max_sessions=1, max_per_principal=1)
    assert isinstance(sessions.sign_in(tokens[0]), Session)

    now[0] = 10.0

    assert isinstance(sessions.sign_in(tokens[1]), Session)


def test_one_tokens_churn_never_forgets_another_tokens_ended_tickets(tmp_path: Path) -> None:
    path = tmp_path / "tokens.json"
    bob_token, carol_token = TokenStore.add(path, "observer", name="bob"), TokenStore.add(path, "observer", name="carol")
    sessions = SessionStore(TokenStore.load(path))
    bob = sessions.sign_in(bob_token)
    assert isinstance(bob, Session)
    sessions.sign_out(bob.session_id)

    for _ in range(200):
        carol = sessions.sign_in(carol_token)
        assert isinstance(carol, Session)
        sessions.sign_out(carol.session_id)

    assert sessions.principal_for_ticket(bob.estop_ticket) == "bob (session ended)"


def test_unknown_tickets_and_non_strings_are_nobody(tmp_path: Path) -> None:
    sessions, token, _ = store_with(tmp_path)
    session = sessions.sign_in(token)
    assert isinstance(session, Session)

    assert [sessions.principal_for_ticket(t) for t in ("", "x", session.session_id, None, 7)] == [None] * 5
