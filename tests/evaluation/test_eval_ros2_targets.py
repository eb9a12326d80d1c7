"""`armwarden eval --backend ros2` with the user's own `--backend-config`: their cell, whose graph
may hold a real arm. Only what moves within an approved plan runs there (the scenarios and the safe
requests); fuzzing, faults and load are left out and said so, and asking for them is refused
before anything starts. (The fake cell's run needs ROS: tests_ros/test_eval_ros2.py.)"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from armwarden.cli import main
from armwarden.evaluation import command
from armwarden.evaluation.runner import EvalResult

EXIT_REFUSED = 2
USERS_CONFIG = Path(__file__).resolve().parents[2] / "examples" / "ros2_fr3.yaml"


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Records every evaluation run, and runs nothing (no daemon, no ROS)."""
    runs: list[Any] = []

    async def run_evaluation(options: Any) -> EvalResult:
        runs.append(options)
        return EvalResult()

    monkeypatch.setattr(command, "run_evaluation", run_evaluation)
    return runs


@pytest.mark.parametrize("asked", [["--kills", "2"], ["--load-seconds", "5"], ["--fuzz-calls", "10"], ["--fuzz-only"]])
def test_faults_load_or_fuzzing_asked_for_on_a_users_cell_are_refused_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], started: list[Any], asked: list[str]) -> None:
    code = main(["eval", "--quick", "--backend", "ros2", "--backend-config", str(USERS_CONFIG), *asked,
                 "--json", str(tmp_path / "eval.json")])

    assert code == EXIT_REFUSED
    assert started == []
    assert f"refusing {asked[0]} with --backend ros2 and your own --backend-config" in capsys.readouterr().err
    assert not (tmp_path / "eval.json").exists()


def test_a_users_cell_gets_the_scenarios_only_and_the_report_says_what_was_left_out(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], started: list[Any]) -> None:
    code = main(["eval", "--quick", "--backend", "ros2", "--backend-config", str(USERS_CONFIG),
                 "--json", str(tmp_path / "eval.json"), "--report", str(tmp_path / "eval.md")])

    (options,) = started
    assert code == 0 and options.on_users_cell and options.cells is None
    assert options.backend_config == USERS_CONFIG
    data = json.loads((tmp_path / "eval.json").read_text())
    for part in ("fuzz", "faults", "load"):
        assert data[part]["run"] is False
        assert "not run on a user's ROS cell" in data[part]["why"], data[part]
    assert "the unsafe scenarios and the safe requests only" in capsys.readouterr().err
