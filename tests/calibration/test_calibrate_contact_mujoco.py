"""`armwarden calibrate-contact` against physics: on the MuJoCo cell, a short calibration through
the whole server recommends limits from the actuators' real torques that keep the margin over what
the observer read, and the section it writes passes check-policy once pasted into the policy."""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import pytest
import yaml

from armwarden.audit.verify import verify_file
from armwarden.calibration.command import EXIT_OK, add_calibrate_arguments, calibrate_command
from armwarden.cli import check_policy_command
from armwarden.policy import bundled_policy, load_policy
from tests.calibration.test_calibrate_contact import executed_ok, pasted, policy_file

pytest.importorskip("mujoco")

MOTIONS = 2


def test_a_short_calibration_in_mujoco_recommends_limits_the_policy_accepts(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "mujoco.yaml"
    config.write_text(yaml.safe_dump({"speedup": 2.0, "objects": []}))
    parser = argparse.ArgumentParser()
    add_calibrate_arguments(parser)
    args = parser.parse_args(["--policy", str(policy_file(tmp_path)), "--backend", "mujoco", "--backend-config",
                              str(config), "--motions", str(MOTIONS), "--seed", "7", "--yes",
                              "--output", str(tmp_path / "section.yaml"), "--audit-log", str(tmp_path / "audit.jsonl")])
    stderr = io.StringIO()

    assert calibrate_command(args, stderr=stderr) == EXIT_OK, stderr.getvalue()

    assert len(executed_ok(tmp_path / "audit.jsonl")) == MOTIONS + 1 and verify_file(tmp_path / "audit.jsonl").ok
    section_text = (tmp_path / "section.yaml").read_text()
    limits = yaml.safe_load(section_text)["joint_torques"]["max_external_torque_nm"]
    summary = stderr.getvalue().split("monitor peak\n")[1]
    for line in summary.splitlines():
        if line.startswith("  fr3_joint"):
            name, residual, after_friction, limit = line.split()[:4]
            assert float(limit) == limits[name] >= 2.0 * float(after_friction) - 1e-9
            assert float(residual) > 0.0  # the observer read the arm's own model error and friction
    policy_path = tmp_path / "calibrated.yaml"
    policy_path.write_text(pasted(bundled_policy("fr3").read_text(), section_text))
    assert check_policy_command(str(policy_path)) == 0, capsys.readouterr().out
    assert dict(load_policy(policy_path).force.joint_torques.max_external_torque_nm) == limits  # type: ignore[union-attr]
