"""`armwarden eval --backend ros2` with the user's own `--backend-config`: their cell, whose graph
may hold a real arm. Only what moves within an approved plan runs there (the scenarios and the safe
requests); fuzzing, faults and load are left out and said so, and asking for them is refused
before anything starts. (The fake cell's run needs ROS: tests_ros/test_eval_ros2.py.)"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
from pathlib import Path
from typing import Any

import anyio
import pytest

from armwarden.cli import main
from armwarden.evaluation import command, runner
from armwarden.evaluation.arguments import add_eval_arguments
from armwarden.evaluation.ros_cell import FakeCells
from armwarden.evaluation.runner import EvalOptions, EvalResult
from armwarden.policy import bundled_policy, load_policy

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


@pytest.mark.parametrize("asked", [["--kills", "2"], ["--backend-deaths", "1"], ["--load-seconds", "5"],
                                   ["--fuzz-calls", "10"], ["--fuzz-only"]])
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
    code = main(["eval", "--quick", "--backend", "ros2", "--backend-config", str(USERS_CONFIG), "--yes",
                 "--json", str(tmp_path / "eval.json"), "--report", str(tmp_path / "eval.md")])

    (options,) = started
    assert code == 0 and options.on_users_cell and options.cells is None
    assert options.backend_config == USERS_CONFIG
    data = json.loads((tmp_path / "eval.json").read_text())
    for part in ("fuzz", "faults", "load"):
        assert data[part]["run"] is False
        assert "not run on a user's ROS cell" in data[part]["why"], data[part]
    assert "the unsafe scenarios and the safe requests only" in capsys.readouterr().err


class Terminal(io.StringIO):
    """A terminal the person answers on."""

    def isatty(self) -> bool:
        return True


def users_cell_eval(tmp_path: Path, stdin: io.StringIO, stderr: io.StringIO, *extra: str) -> int:
    parser = argparse.ArgumentParser()
    add_eval_arguments(parser, ("fake", "ros2"))
    args = parser.parse_args(["--quick", "--backend", "ros2", "--backend-config", str(USERS_CONFIG),
                                      "--json", str(tmp_path / "eval.json"), *extra])
    return command.eval_command(args, stdin=stdin, stderr=stderr)


def test_on_a_users_cell_without_a_terminal_or_yes_nothing_starts(tmp_path: Path, started: list[Any]) -> None:
    stderr = io.StringIO()
    assert users_cell_eval(tmp_path, io.StringIO("yes\n"), stderr) == EXIT_REFUSED  # a pipe is not a person
    assert started == [] and not (tmp_path / "eval.json").exists()
    said = stderr.getvalue()
    assert "will move YOUR arm" in said and "e-stop in reach" in said and "nothing moved" in said


def test_on_a_users_cell_an_answer_other_than_yes_starts_nothing(tmp_path: Path, started: list[Any]) -> None:
    stderr = io.StringIO()
    assert users_cell_eval(tmp_path, Terminal("y\n"), stderr) == EXIT_REFUSED
    assert started == [] and "not approved: nothing moved" in stderr.getvalue()


def test_on_a_users_cell_the_person_typing_yes_starts_the_evaluation(tmp_path: Path, started: list[Any]) -> None:
    assert users_cell_eval(tmp_path, Terminal("yes\n"), io.StringIO()) == 0
    (options,) = started
    assert options.on_users_cell


def _scenarios_run(options: EvalOptions, monkeypatch: pytest.MonkeyPatch) -> tuple[list[str], EvalResult]:
    """The categories of the scenarios `run_evaluation` hands to its daemons (none started), and its result."""
    categories: list[str] = []

    async def with_daemon(options: Any, directory: Path, name: str, overrides: Any, elicits: bool, body: Any) -> None:
        await body(None, directory / f"{name}-journal.jsonl")

    async def run_scenarios(session: Any, journal: Path, scenarios: list[Any], *rest: Any) -> None:
        categories.extend(s.category for s in scenarios)

    async def safe_requests(*args: Any) -> None:
        pass

    monkeypatch.setattr(runner, "_with_daemon", with_daemon)
    monkeypatch.setattr(runner, "_run_scenarios", run_scenarios)
    monkeypatch.setattr(runner, "_safe_requests", safe_requests)
    result = anyio.run(runner.run_evaluation, options)
    return categories, result


def test_on_a_users_cell_the_rate_limit_scenario_that_moves_the_gripper_is_left_out_and_said(
        monkeypatch: pytest.MonkeyPatch) -> None:
    path = bundled_policy()
    options = EvalOptions(path, load_policy(path), "ros2", USERS_CONFIG, safe_count=0, seed=0)

    categories, result = _scenarios_run(options, monkeypatch)

    assert "rate limits" not in categories and "envelope" in categories
    assert any(why.startswith("rate limits: not run on a user's ROS cell") for why in result.skipped), result.skipped


def test_on_the_fake_cell_the_rate_limit_scenario_runs(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    path = bundled_policy()
    options = EvalOptions(path, load_policy(path), "ros2", USERS_CONFIG, safe_count=0, seed=0,
                          cells=FakeCells(tmp_path))  # never started: no daemon's arguments are built

    categories, result = _scenarios_run(options, monkeypatch)

    assert "rate limits" in categories and not options.on_users_cell
    assert not any("user's ROS cell" in why for why in result.skipped)


def test_the_fake_cell_without_rclpy_is_refused_naming_the_ros_venv(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], started: list[Any]) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *rest: None if name == "rclpy" else real(name, *rest))

    assert main(["eval", "--quick", "--backend", "ros2"]) == EXIT_REFUSED
    assert started == []
    assert "needs rclpy in this interpreter" in capsys.readouterr().err
