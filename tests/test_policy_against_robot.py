"""The policy checked against its robot description: `check-policy` and `serve` refuse (exit 2, with
the YAML path) a policy that would silently switch a protection off.

Found by an outside review (issue 24): `workspace.check_links: [fr3_link0]` checked no moving body
at all ("0 collision capsules on 0 links"), and `robot.tcp_frame: fr3_link0` made the TCP path
length zero for every motion, so `max_cartesian_step_m` never triggered. Both passed.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from armwarden.cli import main
from armwarden.policy import apply_overrides, bundled_policy
from tests.helpers import CLI, REPO, child_env

ARM_LINKS = [f"fr3_link{i}" for i in range(1, 8)]
FINGERS = ["fr3_leftfinger", "fr3_rightfinger"]
MOVING_WITH_GEOMETRY = [*ARM_LINKS, "fr3_hand", *FINGERS]  # the fitted capsules (robot.collision_geometry)


def _policy_file(tmp_path: Path, overrides: dict[str, Any]) -> Path:
    document = yaml.safe_load(bundled_policy().read_text(encoding="utf-8"))
    path = tmp_path / "policy.yaml"
    path.write_text(yaml.safe_dump(apply_overrides(document, overrides)), encoding="utf-8")
    return path


def _check_policy(tmp_path: Path, overrides: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(["check-policy", str(_policy_file(tmp_path, overrides))])
    return code, capsys.readouterr().out


def _errors_at(output: str, yaml_path: str) -> list[str]:
    prefix = f"  {yaml_path}: "
    return [line[len(prefix):] for line in output.splitlines() if line.startswith(prefix)]


# ------------------------------------------------------------------ workspace.check_links
@pytest.mark.parametrize(
    ("check_links", "unchecked"),
    [
        (["fr3_link0"], MOVING_WITH_GEOMETRY),  # fixed to the base: no moving body checked
        (["fr3_leftfinger"], [*ARM_LINKS, "fr3_hand", "fr3_rightfinger"]),  # one finger only
        ([*ARM_LINKS, *FINGERS], ["fr3_hand"]),  # the hand left out
        (["fr3_link0", *MOVING_WITH_GEOMETRY[1:]], ["fr3_link1"]),
    ],
)
def test_check_links_leaving_a_moving_body_unchecked_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], check_links: list[str], unchecked: list[str]
) -> None:
    code, output = _check_policy(tmp_path, {"workspace.check_links": check_links}, capsys)

    assert code == 2, output
    assert output.startswith("INVALID:")
    (message,) = _errors_at(output, "workspace.check_links")
    assert f"leaves {len(unchecked)} moving link(s) with collision geometry unchecked: {unchecked}" in message


def test_check_links_naming_every_moving_body_is_accepted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, output = _check_policy(tmp_path, {"workspace.check_links": ["fr3_link0", *MOVING_WITH_GEOMETRY]}, capsys)

    assert code == 0, output
    assert "Robot model: 59 collision capsules on 11 links" in output


# ------------------------------------------------------------------ robot.tcp_frame
@pytest.mark.parametrize("tcp_frame", ["fr3_link0", "fr3_link5", "fr3_link6"])
def test_a_tcp_frame_that_does_not_move_with_the_last_joint_is_refused_naming_the_candidates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], tcp_frame: str
) -> None:
    code, output = _check_policy(tmp_path, {"robot.tcp_frame": tcp_frame}, capsys)

    assert code == 2, output
    (message,) = _errors_at(output, "robot.tcp_frame")
    assert f"TCP frame {tcp_frame!r} does not move with the last joint fr3_joint7" in message
    candidates = message.split("candidates: ", 1)[1].split(", ")
    assert {"fr3_link7", "fr3_link8", "fr3_hand", "fr3_hand_tcp"} <= set(candidates)
    assert not {"fr3_link0", "fr3_link5", "fr3_link6"} & set(candidates)


@pytest.mark.parametrize("tcp_frame", ["fr3_link8", "fr3_hand", "fr3_leftfinger"])
def test_a_tcp_frame_beyond_the_last_joint_is_accepted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], tcp_frame: str
) -> None:
    code, output = _check_policy(tmp_path, {"robot.tcp_frame": tcp_frame}, capsys)

    assert code == 0, output


def test_an_unknown_tcp_frame_is_reported_at_robot_tcp_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, output = _check_policy(tmp_path, {"robot.tcp_frame": "tool0"}, capsys)

    assert code == 2, output
    (message,) = _errors_at(output, "robot.tcp_frame")
    assert "'tool0'" in message and "fr3_hand_tcp" in message


def test_an_unknown_base_frame_is_reported_at_robot_base_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, output = _check_policy(tmp_path, {"robot.base_frame": "world0"}, capsys)

    assert code == 2, output
    (message,) = _errors_at(output, "robot.base_frame")
    assert "'world0'" in message


# ------------------------------------------------------------------ serve refuses the same policies
@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"workspace.check_links": ["fr3_link0"]}, "workspace.check_links: "),
        ({"robot.tcp_frame": "fr3_link0"}, "robot.tcp_frame: "),
    ],
)
def test_serve_refuses_a_policy_that_would_switch_a_check_off_with_exit_2(
    tmp_path: Path, overrides: dict[str, Any], expected: str
) -> None:
    policy = _policy_file(tmp_path, overrides)
    audit = tmp_path / "audit.jsonl"

    result = subprocess.run(
        [*CLI, "serve", "--policy", str(policy), "--audit-log", str(audit)],
        cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120,
    )

    assert result.returncode == 2, result.stderr
    assert expected in result.stderr
    assert result.stdout == ""  # nothing was served
    assert not audit.exists() or "startup" not in audit.read_text(encoding="utf-8")
