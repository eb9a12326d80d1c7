"""ARMWARDEN_AUDIT_KEY as a client passes it: a client that does not expand `${...}` (the MCP
Inspector) hands the daemon the expression itself, which must not silently become the HMAC key;
and `audit verify` with a key that does not match says the key may be wrong or unexpanded."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from armwarden.audit import AuditLog, hmac_key_for_serving
from armwarden.core.errors import ConfigurationError
from tests.helpers import CLI, REPO, child_env

#: what a client hands over when it did not expand the key's reference: shell `${...}`, `$(...)`
#: and `$NAME`, one with a space around it, a reference inside a longer value, Windows `%NAME%`
UNEXPANDED = ["${ARMWARDEN_AUDIT_KEY:-}", "${ARMWARDEN_AUDIT_KEY}", "$(cat key.txt)", "$ARMWARDEN_AUDIT_KEY",
              " ${ARMWARDEN_AUDIT_KEY}", "${ARMWARDEN_AUDIT_KEY} ", "\t$ARMWARDEN_AUDIT_KEY", "key-${SUFFIX}",
              "key-$(cat suffix.txt)", "%ARMWARDEN_AUDIT_KEY%", "%audit_key_1%", "s3cr3t\n", "   "]
#: real keys that merely contain a `$` or a `%`
REAL_KEYS = ["pa$$word${x", "s3cr3t$", "abc$def", "pa$(ss", "$", "$1abc", "100%", "%", "%%", "a%b%c", "%not a name%"]


@pytest.mark.parametrize("expression", ["${ARMWARDEN_AUDIT_KEY:-}", "${ARMWARDEN_AUDIT_KEY}", "$(cat key.txt)",
                                        "$ARMWARDEN_AUDIT_KEY", " ${ARMWARDEN_AUDIT_KEY}", "%ARMWARDEN_AUDIT_KEY%"])
def test_serve_refuses_an_unexpanded_shell_expression_as_audit_key(tmp_path: Path, expression: str) -> None:
    audit = tmp_path / "audit.jsonl"
    env = {**child_env(), "ARMWARDEN_AUDIT_KEY": expression}

    result = subprocess.run([*CLI, "serve", "--backend", "fake", "--audit-log", str(audit)], cwd=REPO, env=env,
                            stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)

    assert result.returncode == 2, result.stderr
    assert "ARMWARDEN_AUDIT_KEY" in result.stderr and "unexpanded" in result.stderr, result.stderr
    assert expression in result.stderr
    assert not audit.exists()  # refused before the log was opened: nothing keyed with the literal


@pytest.mark.parametrize("key", REAL_KEYS)
def test_a_real_key_that_merely_contains_a_dollar_or_a_percent_is_used(key: str) -> None:
    assert hmac_key_for_serving({"ARMWARDEN_AUDIT_KEY": key}) == key.encode()


def test_no_key_is_an_unkeyed_log() -> None:
    assert hmac_key_for_serving({}) is None
    assert hmac_key_for_serving({"ARMWARDEN_AUDIT_KEY": ""}) is None


@pytest.mark.parametrize("expression", UNEXPANDED)
def test_the_serving_key_refuses_an_unexpanded_reference(expression: str) -> None:
    with pytest.raises(ConfigurationError, match="unexpanded") as refused:
        hmac_key_for_serving({"ARMWARDEN_AUDIT_KEY": expression})

    assert repr(expression) in str(refused.value)


def keyed_log(path: Path, key: bytes) -> Path:
    with AuditLog(path, hmac_key=key) as log:
        log.append("startup")
        log.append("tool_call", tool="get_robot_state", outcome="ok")
    return path


def test_verify_with_a_key_that_does_not_match_says_it_may_be_wrong_or_unexpanded(tmp_path: Path) -> None:
    path = keyed_log(tmp_path / "audit.jsonl", b"${ARMWARDEN_AUDIT_KEY:-}")  # what an old daemon wrote
    env = {**child_env(), "ARMWARDEN_AUDIT_KEY": "the real key"}

    result = subprocess.run([*CLI, "audit", "verify", str(path)], cwd=REPO, env=env, capture_output=True, text=True,
                            timeout=60)

    assert result.returncode == 1
    assert result.stdout.startswith("FAILED at line 1: hash mismatch")
    assert "wrong" in result.stdout and "unexpanded" in result.stdout and "ARMWARDEN_AUDIT_KEY" in result.stdout


def test_verify_without_a_key_of_a_keyed_log_also_names_an_unexpanded_key(tmp_path: Path) -> None:
    path = keyed_log(tmp_path / "audit.jsonl", b"${ARMWARDEN_AUDIT_KEY:-}")

    result = subprocess.run([*CLI, "audit", "verify", str(path)], cwd=REPO, env=child_env(), capture_output=True,
                            text=True, timeout=60)

    assert result.returncode == 1
    assert "no HMAC key given" in result.stdout and "unexpanded" in result.stdout


def strings_in(node: object) -> list[str]:
    if isinstance(node, dict):
        return [s for key, value in node.items() for s in [key, *strings_in(value)]]
    if isinstance(node, list):
        return [s for item in node for s in strings_in(item)]
    return [node] if isinstance(node, str) else []


@pytest.mark.parametrize("example", sorted(p.name for p in (REPO / "examples").glob("*.json")))
def test_no_client_config_example_carries_a_shell_expression(example: str) -> None:
    """Clients that do not expand `${...}` would pass it on literally (and the daemon refuses it)."""
    document = json.loads((REPO / "examples" / example).read_text(encoding="utf-8"))

    assert [s for s in strings_in(document) if "${" in s or "$(" in s] == []
