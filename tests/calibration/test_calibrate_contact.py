"""`armwarden calibrate-contact` end to end on the fake arm: the motions go through the Guard and
are audited, the recommended section pasted into the policy passes check-policy, the limits keep
the margin over what was seen, a run without approval moves nothing, and a contact or an e-stop
during the calibration ends it (exit 1, nothing recommended)."""

from __future__ import annotations

import argparse
import io
import os
import signal
from pathlib import Path
from typing import Any

import anyio
import pytest
import yaml

from armwarden.audit.verify import verify_file
from armwarden.calibration import run as calibration_run
from armwarden.calibration.command import EXIT_OK, EXIT_REFUSED, EXIT_STOPPED, add_calibrate_arguments, calibrate_command
from armwarden.calibration.friction_fit import MIN_FORCE_ROOM_N, MIN_LIMIT_NM
from armwarden.calibration.run import CalibrationOptions, run_calibration
from armwarden.cli import check_policy_command
from armwarden.daemon import startup
from armwarden.policy import bundled_policy, load_policy
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from tests.helpers import records_of
from tests.server.harness import SPEEDUP

MOTIONS = 2


def policy_document() -> dict[str, Any]:
    """The bundled FR3 policy with the longest wrench timeout, as tests/server/harness.py gives its
    policies: the fake's servo thread and the monitor share this test process and stall together on
    a loaded machine, which the monitor rightly takes for a lost reading (tested elsewhere)."""
    document = yaml.safe_load(bundled_policy("fr3").read_text())
    document["force"]["wrench_timeout_s"] = MAX_WRENCH_TIMEOUT_S
    return document


def policy_file(tmp_path: Path, section: str | None = None, **changes: Any) -> Path:
    """`policy_document()` with `changes` to one of its sections, written to a file."""
    document = policy_document()
    if section is not None:
        document[section].update(changes)
    path = tmp_path / "policy.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def fake_config(tmp_path: Path, noise_nm: float = 0.0) -> Path:
    """The fake at the test harness's speed (tests/server/harness.py), with `noise_nm` of Gaussian
    noise on its measured torques."""
    path = tmp_path / f"fake-{noise_nm:g}.yaml"
    path.write_text(yaml.safe_dump({"speedup": SPEEDUP["fake"], "joint_torque_noise_nm": noise_nm}))
    return path


def arguments(tmp_path: Path, *extra: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_calibrate_arguments(parser)
    return parser.parse_args(["--policy", str(policy_file(tmp_path)), "--backend", "fake",
                              "--backend-config", str(fake_config(tmp_path)), "--motions", str(MOTIONS),
                              "--output", str(tmp_path / "section.yaml"), "--audit-log", str(tmp_path / "audit.jsonl"),
                              "--operator", "alice", *extra])


class NotATerminal(io.StringIO):
    def isatty(self) -> bool:
        return False


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def calibrated(args: argparse.Namespace) -> str:
    """Run the command, which must succeed; what it said on stderr."""
    stderr = io.StringIO()
    assert calibrate_command(args, stderr=stderr) == EXIT_OK, stderr.getvalue()
    return stderr.getvalue()


def pasted(policy_text: str, section_text: str) -> str:
    """`policy_text` with its `force.joint_torques` block replaced by `section_text`, indented under
    `force:` as the section's own comment tells the user to paste it."""
    lines = policy_text.splitlines()
    start = lines.index("  joint_torques:")
    end = next(i for i in range(start + 1, len(lines)) if not lines[i].startswith("    "))
    return "\n".join([*lines[:start], *("  " + line for line in section_text.splitlines()), *lines[end:]]) + "\n"


def executed_ok(audit: Path) -> list[dict[str, Any]]:
    return [r for r in records_of(audit) if r["event"] == "tool_call" and r["tool"] == "execute_plan"
            and r["outcome"] == "ok"]


def backends_built(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Every backend the calibration builds (through the daemon's start-up, as `serve`), kept."""
    built: list[Any] = []
    build = startup.build_backend  # pyright: ignore[reportPrivateImportUsage] - the name start-up looks up

    def keep(*args: Any, **kwargs: Any) -> Any:
        built.append(build(*args, **kwargs))
        return built[-1]

    monkeypatch.setattr(startup, "build_backend", keep)
    return built


def with_progress(monkeypatch: pytest.MonkeyPatch, progress: Any) -> None:
    """Run the command's calibration with `progress` called after each motion."""
    real_run = calibration_run.run_calibration

    async def run(options: Any, **_: Any) -> Any:
        return await real_run(options, progress=progress)

    monkeypatch.setattr("armwarden.calibration.command.run_calibration", run)


def test_the_recommended_section_pasted_into_the_policy_passes_check_policy(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    calibrated(arguments(tmp_path, "--yes"))
    section_text = (tmp_path / "section.yaml").read_text()
    policy_path = tmp_path / "calibrated.yaml"
    policy_path.write_text(pasted(bundled_policy("fr3").read_text(), section_text))

    assert check_policy_command(str(policy_path)) == 0, capsys.readouterr().out
    limits = load_policy(policy_path).force.joint_torques
    recommended = yaml.safe_load(section_text)["joint_torques"]["max_external_torque_nm"]
    assert limits is not None and dict(limits.max_external_torque_nm) == recommended
    assert limits.max_tcp_force_n == yaml.safe_load(section_text)["joint_torques"]["max_tcp_force_n"]
    assert tuple(recommended) == load_policy(policy_path).robot.joint_names


def test_every_calibration_motion_went_through_the_guard_and_is_audited(tmp_path: Path) -> None:
    calibrated(arguments(tmp_path, "--yes"))
    records = records_of(tmp_path / "audit.jsonl")
    executed = executed_ok(tmp_path / "audit.jsonl")
    assert len(executed) == MOTIONS + 1  # and back home
    # each monitored from the joint torques: the peak external torque of every joint is in its record
    assert all(len(r["extra"]["result"]["max_external_torques_nm"]) == 7 for r in executed)
    started = [r for r in records if r["event"] == "calibration_started"]
    assert started and started[0]["operator"] == "alice"  # who approved it, before anything moved
    assert records.index(started[0]) < records.index(executed[0])
    finished = [r for r in records if r["event"] == "calibration_finished"]
    assert finished and finished[0]["outcome"] == "ok"
    assert verify_file(tmp_path / "audit.jsonl").ok


def test_the_recommended_limits_exceed_what_was_seen_by_the_margin(tmp_path: Path) -> None:
    options = CalibrationOptions(policy=load_policy(policy_file(tmp_path)), backend="fake",
                                 backend_config=fake_config(tmp_path), motions=MOTIONS,
                                 margin=3.0, audit_log=tmp_path / "audit.jsonl")
    result = anyio.run(run_calibration, options)

    assert result.stopped is None and result.recommendations
    for joint in result.recommendations:
        assert joint.samples > 20
        assert joint.limit_nm >= max(MIN_LIMIT_NM, 3.0 * joint.peak_after_friction_nm)
        assert joint.limit_nm <= max(MIN_LIMIT_NM, 3.0 * joint.peak_after_friction_nm) + 0.01
        assert joint.margin >= 3.0
        assert result.section["max_external_torque_nm"][joint.name] == joint.limit_nm
    assert result.force_limit_n is not None and result.section["max_tcp_force_n"] == result.force_limit_n
    assert result.force_limit_n >= max(3.0 * result.peak_force_n, result.peak_force_n + MIN_FORCE_ROOM_N)


def calibrate(tmp_path: Path, noise_nm: float) -> Any:
    """A short calibration on the fake, whose measured torques carry `noise_nm` of Gaussian noise."""
    options = CalibrationOptions(policy=load_policy(policy_file(tmp_path)), backend="fake",
                                 backend_config=fake_config(tmp_path, noise_nm),
                                 motions=MOTIONS, audit_log=tmp_path / f"audit-{noise_nm:g}.jsonl")
    return anyio.run(run_calibration, options)


def test_the_samples_replayed_are_the_monitors_own(tmp_path: Path) -> None:
    result = calibrate(tmp_path, noise_nm=1.0)
    # the peak per joint each execution reported (rounded to 1e-4 N·m), against the same from the replay
    assert result.monitor_peaks_nm == pytest.approx(result.replayed_peaks_nm, abs=1e-4)
    assert min(result.monitor_peaks_nm) > 0.5  # the noise, seen by both


def test_noisier_torques_raise_the_recommended_limits(tmp_path: Path) -> None:
    quiet, noisy = (calibrate(tmp_path, noise_nm) for noise_nm in (0.0, 1.0))
    assert all(q.limit_nm <= n.limit_nm for q, n in zip(quiet.recommendations, noisy.recommendations, strict=True))
    assert sum(n.limit_nm for n in noisy.recommendations) > 1.5 * sum(q.limit_nm for q in quiet.recommendations)


def test_the_summary_on_stderr_gives_each_joints_residual_limit_and_margin(tmp_path: Path) -> None:
    said = calibrated(arguments(tmp_path, "--yes"))
    section = yaml.safe_load((tmp_path / "section.yaml").read_text())["joint_torques"]
    summary = said.split("monitor peak\n")[1]  # after the table's header
    rows = {line.split()[0]: line.split() for line in summary.splitlines() if line.startswith("  fr3_joint")}
    assert set(rows) == set(section["max_external_torque_nm"])
    for name, row in rows.items():
        residual, limit, margin = float(row[1]), float(row[3]), row[4]
        assert limit == section["max_external_torque_nm"][name]
        assert margin == "inf" or float(margin.rstrip("x")) >= 2.0
        assert limit > residual


def test_without_a_terminal_or_yes_nothing_moves(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    built = backends_built(monkeypatch)
    stderr = io.StringIO()
    assert calibrate_command(arguments(tmp_path), stdin=NotATerminal(), stderr=stderr) == EXIT_REFUSED
    assert "nothing moved" in stderr.getvalue()
    assert built == []  # no backend was even built
    assert not (tmp_path / "audit.jsonl").exists() and not (tmp_path / "section.yaml").exists()


def test_the_terminal_prompt_lists_the_motions_joint_ranges_and_speeds(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    built = backends_built(monkeypatch)
    stderr = io.StringIO()
    assert calibrate_command(arguments(tmp_path), stdin=Terminal("no\n"), stderr=stderr) == EXIT_REFUSED
    prompt = stderr.getvalue()
    assert f"through {MOTIONS} seeded random motions" in prompt and "Type yes to start" in prompt
    assert all(f"  fr3_joint{j}: " in prompt for j in range(1, 8)) and "rad/s" in prompt
    assert built == [] and not (tmp_path / "audit.jsonl").exists()


def test_a_contact_during_calibration_ends_it_and_recommends_nothing(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    built = backends_built(monkeypatch)

    def push_after_the_first_motion(line: str) -> None:
        if line.startswith("motion 1/"):
            built[0].push("fr3_link5", (0.0, 0.0, 60.0))  # over twice joint 4's limit: nothing may move

    with_progress(monkeypatch, push_after_the_first_motion)
    stderr = io.StringIO()
    assert calibrate_command(arguments(tmp_path, "--yes"), stderr=stderr) == EXIT_STOPPED
    said = stderr.getvalue().splitlines()[-1]
    # refused before motion 2 moved (IN_CONTACT), or stopped by the monitor as it began (FORCE_LIMIT)
    assert "nothing more moved" in said and ("[IN_CONTACT]" in said or "[FORCE_LIMIT]" in said), said
    assert not (tmp_path / "section.yaml").exists()
    assert len(executed_ok(tmp_path / "audit.jsonl")) == 1, said
    finished = [r for r in records_of(tmp_path / "audit.jsonl") if r["event"] == "calibration_finished"]
    assert finished[0]["outcome"] == "stopped" and finished[0]["detail"] in said


@pytest.mark.parametrize("signum", [signal.SIGUSR1, signal.SIGINT], ids=["SIGUSR1", "Ctrl-C"])
def test_an_estop_during_calibration_ends_it_and_recommends_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                    signum: int) -> None:
    def signal_after_the_first_motion(line: str) -> None:
        if line.startswith("motion 1/"):
            os.kill(os.getpid(), signum)

    with_progress(monkeypatch, signal_after_the_first_motion)
    stderr = io.StringIO()
    assert calibrate_command(arguments(tmp_path, "--yes"), stderr=stderr) == EXIT_STOPPED
    assert "nothing more moved" in stderr.getvalue()
    assert not (tmp_path / "section.yaml").exists()
    records = records_of(tmp_path / "audit.jsonl")
    assert len(executed_ok(tmp_path / "audit.jsonl")) == 1
    assert [r["event"] for r in records].count("estop") == 1
    finished = [r for r in records if r["event"] == "calibration_finished"]
    assert finished[0]["outcome"] == "stopped"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handlers are given back


def test_a_policy_without_joint_torque_limits_is_calibrated_under_provisional_ones(tmp_path: Path) -> None:
    document = policy_document()
    del document["force"]["joint_torques"]
    path = tmp_path / "bare.yaml"
    path.write_text(yaml.safe_dump(document))
    assert load_policy(path).force.joint_torques is None
    args = arguments(tmp_path, "--yes")
    args.policy = path
    calibrated(args)
    assert "max_external_torque_nm" in (tmp_path / "section.yaml").read_text()


def test_where_the_policy_asks_for_every_motion_the_calibrations_approval_answers(tmp_path: Path) -> None:
    args = arguments(tmp_path, "--yes")
    args.policy = policy_file(tmp_path, "approval", mode="always")
    calibrated(args)
    executed = executed_ok(tmp_path / "audit.jsonl")
    assert len(executed) == MOTIONS + 1
    assert all(r["extra"]["approval"]["via"] == "elicitation" and r["extra"]["approval"]["operator"] == "alice"
               for r in executed)


def test_a_calibration_in_which_no_motion_ran_recommends_nothing(tmp_path: Path) -> None:
    args = arguments(tmp_path, "--yes")
    args.policy = policy_file(tmp_path, "motion", soft_joint_step_rad=0.01)  # every motion needs its own look
    stderr = io.StringIO()
    assert calibrate_command(args, stderr=stderr) == EXIT_STOPPED
    said = stderr.getvalue()
    assert "no motion ran" in said and all(f"skipped motion {i}: needs_approval" in said for i in range(1, MOTIONS + 1))
    assert len(executed_ok(tmp_path / "audit.jsonl")) <= 1  # at most the return home, from home
    assert not (tmp_path / "section.yaml").exists()
