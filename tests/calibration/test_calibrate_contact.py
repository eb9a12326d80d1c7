"""`armwarden calibrate-contact` end to end on the fake arm: the motions go through the Guard and
are audited, the recommended section loads into the policy, a run without approval moves nothing,
and a contact during the calibration ends it."""

from __future__ import annotations

import argparse
import io
from pathlib import Path
from typing import Any

import pytest
import yaml

from armwarden.audit.verify import verify_file
from armwarden.calibration import run as calibration_run
from armwarden.calibration.command import EXIT_OK, EXIT_REFUSED, EXIT_STOPPED, add_calibrate_arguments, calibrate_command
from armwarden.policy import bundled_policy, load_policy, parse_policy
from tests.helpers import records_of

MOTIONS = 3


def arguments(tmp_path: Path, *extra: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_calibrate_arguments(parser)
    return parser.parse_args(["--policy", str(bundled_policy("fr3")), "--backend", "fake", "--motions", str(MOTIONS),
                              "--output", str(tmp_path / "section.yaml"), "--audit-log", str(tmp_path / "audit.jsonl"),
                              "--operator", "alice", *extra])


class NotATerminal(io.StringIO):
    def isatty(self) -> bool:
        return False


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_calibration_writes_a_section_the_policy_accepts(tmp_path: Path) -> None:
    assert calibrate_command(arguments(tmp_path, "--yes"), stderr=io.StringIO()) == EXIT_OK
    section = yaml.safe_load((tmp_path / "section.yaml").read_text())["joint_torques"]
    document = yaml.safe_load(bundled_policy("fr3").read_text())
    document["force"]["joint_torques"] = section
    policy = parse_policy(document, base_dir=bundled_policy("fr3").parent)
    limits = policy.force.joint_torques
    assert limits is not None and tuple(limits.max_external_torque_nm) == policy.robot.joint_names


def test_every_calibration_motion_went_through_the_guard_and_is_audited(tmp_path: Path) -> None:
    calibrate_command(arguments(tmp_path, "--yes"), stderr=io.StringIO())
    records = records_of(tmp_path / "audit.jsonl")
    executed = [r for r in records if r["event"] == "tool_call" and r["tool"] == "execute_plan" and r["outcome"] == "ok"]
    assert len(executed) == MOTIONS + 1  # and back home
    started = [r for r in records if r["event"] == "calibration_started"]
    assert started and started[0]["operator"] == "alice"  # who approved it, before anything moved
    assert records.index(started[0]) < records.index(executed[0])
    assert records[-1]["event"] == "calibration_finished" and records[-1]["outcome"] == "ok"
    assert verify_file(tmp_path / "audit.jsonl").ok


def test_the_recommended_limits_exceed_what_was_seen_by_the_margin(tmp_path: Path) -> None:
    stderr = io.StringIO()
    calibrate_command(arguments(tmp_path, "--yes", "--margin", "3"), stderr=stderr)
    text = (tmp_path / "section.yaml").read_text()
    assert "margin 3" in text
    for line in text.splitlines():
        if "->" in line and "x margin" in line:
            margin = float(line.split("(")[1].split("x margin")[0])
            assert margin >= 3.0 - 0.01


def test_without_a_terminal_or_yes_nothing_moves(tmp_path: Path) -> None:
    stderr = io.StringIO()
    assert calibrate_command(arguments(tmp_path), stdin=NotATerminal(), stderr=stderr) == EXIT_REFUSED
    assert "nothing moved" in stderr.getvalue()
    assert not (tmp_path / "audit.jsonl").exists() and not (tmp_path / "section.yaml").exists()


def test_a_human_who_does_not_type_yes_moves_nothing(tmp_path: Path) -> None:
    assert calibrate_command(arguments(tmp_path), stdin=Terminal("no\n"), stderr=io.StringIO()) == EXIT_REFUSED
    assert not (tmp_path / "audit.jsonl").exists()


def test_a_contact_during_calibration_ends_it_and_recommends_nothing(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    built: list[Any] = []
    build = calibration_run.build_backend  # pyright: ignore[reportPrivateImportUsage] - the name the run looks up

    def keep(*args: Any, **kwargs: Any) -> Any:
        built.append(build(*args, **kwargs))
        return built[-1]

    def push_after_the_first_motion(line: str) -> None:
        if line.startswith("motion 1/"):
            built[0].push("fr3_link5", (0.0, 0.0, 60.0))  # over twice joint 4's limit: nothing may move

    monkeypatch.setattr(calibration_run, "build_backend", keep)
    real_run = calibration_run.run_calibration

    async def with_push(options: Any, progress: Any = None) -> Any:
        return await real_run(options, progress=push_after_the_first_motion)

    monkeypatch.setattr("armwarden.calibration.command.run_calibration", with_push)
    stderr = io.StringIO()
    assert calibrate_command(arguments(tmp_path, "--yes"), stderr=stderr) == EXIT_STOPPED
    assert "nothing more moved" in stderr.getvalue() and "IN_CONTACT" in stderr.getvalue()
    assert not (tmp_path / "section.yaml").exists()
    executed = [r for r in records_of(tmp_path / "audit.jsonl") if r["event"] == "tool_call"
                and r["tool"] == "execute_plan" and r["outcome"] == "ok"]
    assert len(executed) == 1


def test_a_policy_without_joint_torque_limits_is_calibrated_under_provisional_ones(tmp_path: Path) -> None:
    document = yaml.safe_load(bundled_policy("fr3").read_text())
    del document["force"]["joint_torques"]
    document["robot"]["description"] = "builtin:fr3"
    path = tmp_path / "bare.yaml"
    path.write_text(yaml.safe_dump(document))
    assert load_policy(path).force.joint_torques is None
    args = arguments(tmp_path, "--yes")
    args.policy = path
    assert calibrate_command(args, stderr=io.StringIO()) == EXIT_OK
    assert "max_external_torque_nm" in (tmp_path / "section.yaml").read_text()
