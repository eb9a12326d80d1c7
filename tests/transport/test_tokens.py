"""Token file: add/list/revoke, strict loading, permissions, constant-time authentication, CLI."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import stat
from pathlib import Path

import pytest

from armwarden.core.errors import ConfigurationError
from armwarden.transport import tokens as tokens_module
from armwarden.transport.tokens import (
    Principal,
    TokenStore,
    tokens_add_command,
    tokens_list_command,
    tokens_revoke_command,
)


@pytest.fixture
def token_path(tmp_path: Path) -> Path:
    return tmp_path / "tokens.json"


def _write_raw(path: Path, data: object, mode: int = 0o600) -> None:
    path.write_text(json.dumps(data))
    path.chmod(mode)


def _entry(name: str = "alice", role: str = "operator", digest: str = "a" * 64) -> dict[str, str]:
    return {"name": name, "role": role, "token_sha256": digest, "created": "2025-01-01T12:00:00+00:00"}


def test_add_returns_prefixed_token_and_stores_only_its_hash(token_path: Path) -> None:
    token = TokenStore.add(token_path, "operator", name="alice")

    text = token_path.read_text()
    assert token.startswith("aw_") and len(token) > 40
    assert token not in text and token[3:] not in text
    assert hashlib.sha256(token.encode()).hexdigest() in text


def test_add_creates_file_with_mode_0600(token_path: Path) -> None:
    TokenStore.add(token_path, "observer")
    TokenStore.add(token_path, "operator")  # rewriting keeps the mode

    assert stat.S_IMODE(token_path.stat().st_mode) == 0o600


def test_add_without_name_numbers_tokens_per_role(token_path: Path) -> None:
    TokenStore.add(token_path, "observer")
    TokenStore.add(token_path, "observer")
    TokenStore.add(token_path, "operator")

    assert [info.name for info in TokenStore.list(token_path)] == ["observer-1", "observer-2", "operator-1"]


def test_add_refuses_duplicate_name(token_path: Path) -> None:
    TokenStore.add(token_path, "operator", name="alice")

    with pytest.raises(ConfigurationError, match="already exists"):
        TokenStore.add(token_path, "observer", name="alice")


def test_add_refuses_unknown_role_naming_valid_roles(token_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="observer, operator"):
        TokenStore.add(token_path, "admin")
    assert not token_path.exists()


def test_list_shows_name_role_created_and_fingerprint(token_path: Path) -> None:
    token = TokenStore.add(token_path, "observer", name="dash")

    (info,) = TokenStore.list(token_path)
    assert (info.name, info.role) == ("dash", "observer")
    assert info.created.tzinfo is not None
    assert hashlib.sha256(token.encode()).hexdigest().startswith(info.fingerprint)
    assert len(info.fingerprint) == 12


def test_revoke_removes_only_the_named_token(token_path: Path) -> None:
    TokenStore.add(token_path, "operator", name="alice")
    TokenStore.add(token_path, "observer", name="bob")

    assert TokenStore.revoke(token_path, "alice") is True
    assert [info.name for info in TokenStore.list(token_path)] == ["bob"]


def test_revoke_of_unknown_name_returns_false(token_path: Path) -> None:
    TokenStore.add(token_path, "operator", name="alice")

    assert TokenStore.revoke(token_path, "carol") is False


def test_authenticate_returns_the_principal_of_each_token(token_path: Path) -> None:
    alice = TokenStore.add(token_path, "operator", name="alice")
    bob = TokenStore.add(token_path, "observer", name="bob")
    store = TokenStore.load(token_path)

    assert store.authenticate(alice) == Principal("alice", "operator")
    assert store.authenticate(bob) == Principal("bob", "observer")


@pytest.mark.parametrize("presented", ["", "aw_wrong", "x" * 10_000])
def test_authenticate_rejects_unknown_tokens(token_path: Path, presented: str) -> None:
    token = TokenStore.add(token_path, "operator")
    store = TokenStore.load(token_path)

    assert store.authenticate(presented) is None
    assert store.authenticate(token + "x") is None


def test_authenticate_compares_every_stored_hash_even_after_a_match(
    token_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    first = TokenStore.add(token_path, "operator")
    for _ in range(4):
        TokenStore.add(token_path, "observer")
    store = TokenStore.load(token_path)
    calls: list[tuple[str, str]] = []
    real = tokens_module.hmac.compare_digest

    def counting(a: str, b: str) -> bool:
        calls.append((a, b))
        return real(a, b)

    monkeypatch.setattr(tokens_module.hmac, "compare_digest", counting)

    assert store.authenticate(first) == Principal("operator-1", "operator")
    assert len(calls) == 5


def test_loaded_store_stops_accepting_a_revoked_token(token_path: Path) -> None:
    token = TokenStore.add(token_path, "operator", name="alice")
    store = TokenStore.load(token_path)
    assert store.authenticate(token) is not None

    TokenStore.revoke(token_path, "alice")

    assert store.authenticate(token) is None


def test_loaded_store_accepts_a_token_added_later(token_path: Path) -> None:
    TokenStore.add(token_path, "observer")
    store = TokenStore.load(token_path)

    token = TokenStore.add(token_path, "operator", name="late")

    assert store.authenticate(token) == Principal("late", "operator")


def test_loaded_store_fails_closed_when_file_becomes_invalid(token_path: Path) -> None:
    token = TokenStore.add(token_path, "operator")
    store = TokenStore.load(token_path)

    token_path.write_text("{ not json")

    assert store.authenticate(token) is None


def test_load_of_missing_file_is_configuration_error(token_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="does not exist"):
        TokenStore.load(token_path)


def test_load_refuses_unknown_keys(token_path: Path) -> None:
    _write_raw(token_path, {"version": 1, "tokens": [{**_entry(), "token": "aw_plaintext"}]})

    with pytest.raises(ConfigurationError, match=r"tokens\.0\.token"):
        TokenStore.load(token_path)


def test_load_refuses_duplicate_names(token_path: Path) -> None:
    _write_raw(token_path, {"version": 1, "tokens": [_entry(digest="a" * 64), _entry(digest="b" * 64)]})

    with pytest.raises(ConfigurationError, match="duplicate name 'alice'"):
        TokenStore.load(token_path)


def test_load_refuses_duplicate_hashes(token_path: Path) -> None:
    _write_raw(token_path, {"version": 1, "tokens": [_entry(name="a"), _entry(name="b")]})

    with pytest.raises(ConfigurationError, match="duplicate token_sha256"):
        TokenStore.load(token_path)


def test_load_refuses_malformed_hash_and_role(token_path: Path) -> None:
    _write_raw(token_path, {"version": 1, "tokens": [_entry(role="root", digest="XYZ")]})

    with pytest.raises(ConfigurationError) as raised:
        TokenStore.load(token_path)
    assert "tokens.0.role" in str(raised.value) and "tokens.0.token_sha256" in str(raised.value)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_load_refuses_file_writable_by_others(token_path: Path) -> None:
    TokenStore.add(token_path, "operator")
    token_path.chmod(0o622)

    with pytest.raises(ConfigurationError, match="chmod 600"):
        TokenStore.load(token_path)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="giving a file away needs root")
def test_load_refuses_a_file_owned_by_another_user(token_path: Path) -> None:
    TokenStore.add(token_path, "operator")
    os.chown(token_path, 65534, 65534)  # nobody

    with pytest.raises(ConfigurationError, match="belongs to user id 65534"):
        TokenStore.load(token_path)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_a_chmod_after_a_refused_edit_is_picked_up_without_another_edit(token_path: Path) -> None:
    token = TokenStore.add(token_path, "operator", name="alice")
    store = TokenStore.load(token_path)
    token_path.chmod(0o664)
    token_path.write_text(json.dumps(json.loads(token_path.read_text()), indent=4))  # edited while group-writable
    assert store.authenticate(token) is None  # fails closed
    token_path.chmod(0o600)  # what the refusal says to do; the content and its mtime stay as they are

    principal = store.authenticate(token)
    assert principal is not None and principal.name == "alice"


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_load_warns_about_file_readable_by_others(token_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    TokenStore.add(token_path, "operator")
    token_path.chmod(0o644)

    with caplog.at_level(logging.WARNING, logger="armwarden.transport.token_storage"):
        store = TokenStore.load(token_path)

    assert len(store) == 1
    assert "readable by group or others" in caplog.text


def test_yaml_token_file_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "tokens.yaml"
    token = TokenStore.add(path, "observer", name="viewer")

    assert path.read_text().startswith("version: 1")
    assert TokenStore.load(path).authenticate(token) == Principal("viewer", "observer")


def test_tokens_add_command_prints_token_only_on_stdout(token_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert tokens_add_command(token_path, "operator", None) == 0

    out, err = capsys.readouterr()
    token = out.strip()
    assert out == token + "\n" and token.startswith("aw_")
    assert "operator-1" in err and "only this once" in err and token not in err
    assert TokenStore.load(token_path).authenticate(token) == Principal("operator-1", "operator")


def test_tokens_list_command_never_prints_a_token(token_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    token = TokenStore.add(token_path, "operator", name="alice")

    assert tokens_list_command(token_path) == 0

    out, _ = capsys.readouterr()
    assert "alice" in out and "operator" in out and "sha256:" in out
    assert token not in out and hashlib.sha256(token.encode()).hexdigest() not in out


def test_tokens_revoke_command_exit_status(token_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    TokenStore.add(token_path, "operator", name="alice")

    assert tokens_revoke_command(token_path, "alice") == 0
    assert tokens_revoke_command(token_path, "alice") == 1
    assert tokens_revoke_command(token_path.with_name("missing.json"), "alice") == 2
    assert "does not exist" in capsys.readouterr().err
