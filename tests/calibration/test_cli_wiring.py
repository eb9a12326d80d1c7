"""`armwarden calibrate-contact` as the shell runs it: the subcommand is wired, refuses without a
terminal or --yes, and its weight (the daemon, the Guard, Pinocchio's models) is loaded only when
it runs, never by the parser every other subcommand (`armwarden estop` among them) builds."""

from __future__ import annotations

import subprocess
from pathlib import Path

from armwarden.policy import bundled_policy
from tests.helpers import CLI, REPO, child_env, modules_the_parser_loads


def test_from_the_shell_without_a_terminal_or_yes_it_refuses_and_nothing_moves(tmp_path: Path) -> None:
    audit = tmp_path / "audit.jsonl"
    result = subprocess.run([*CLI, "calibrate-contact", "--policy", str(bundled_policy("fr3")), "--backend", "fake",
                             "--audit-log", str(audit)], cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL,
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 2, result.stderr
    assert "no terminal to ask on and no --yes: nothing moved" in result.stderr
    assert "through 30 seeded random motions" in result.stderr  # what it would have moved, said all the same
    assert result.stdout == "" and not audit.exists()


def test_the_command_line_parser_does_not_load_the_calibration() -> None:
    assert modules_the_parser_loads("armwarden.calibration") == ["armwarden.calibration",
                                                                 "armwarden.calibration.arguments"]
