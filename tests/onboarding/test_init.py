"""`armwarden init` on arms the project has never seen: what it infers, the files it writes, that
they pass `check-policy`, that a second run writes the same bytes, and what it refuses."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from armwarden.cli import main
from armwarden.core.errors import RobotModelError
from armwarden.onboarding import InitOptions, run_init
from armwarden.onboarding.fitted import FitSettings, finger_links, fit_links
from armwarden.onboarding.home import stationary
from armwarden.policy import load_policy
from armwarden.robot.description_files import load_description
from armwarden.robot.fitted_file import load_fitted
from armwarden.robot.link_meshes import link_meshes
from armwarden.robot.model import RobotModel
from tests.onboarding.conftest import QUICK_FIT, InitRun, init_arm
from tests.robot.generated_arm import write_random_arm


def test_init_infers_the_arm_chain_and_frames_of_the_description(six_joint_arm: InitRun) -> None:
    policy = six_joint_arm.result.runtime.policy
    arm = six_joint_arm.arm
    assert policy.robot.joint_names == arm.joint_names
    assert (policy.robot.base_frame, policy.robot.tcp_frame) == (arm.base_frame, arm.tcp_frame)


def test_the_written_policy_passes_check_policy(six_joint_arm: InitRun, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-policy", str(six_joint_arm.options.output)]) == 0
    assert "home configuration passes the envelope" in capsys.readouterr().out


def test_the_policy_points_at_the_description_and_fitted_file_relative_to_itself(six_joint_arm: InitRun) -> None:
    text = six_joint_arm.options.output.read_text(encoding="utf-8")
    assert "description: ../arm/" in text and "collision_geometry: arm.fitted.yaml" in text
    fitted = load_fitted(six_joint_arm.options.fitted_path)
    assert set(fitted.links) >= {c.link for c in six_joint_arm.result.runtime.robot.capsules}


def test_home_is_collision_free_inside_the_limits_and_above_the_table(six_joint_arm: InitRun) -> None:
    runtime = six_joint_arm.result.runtime
    home = np.array(runtime.policy.robot.home_joint_positions)
    assert runtime.envelope.check(stationary(runtime.envelope, home)).violations == ()
    assert runtime.robot.within_limits(home, runtime.policy.motion.joint_limit_margin_rad)
    assert runtime.robot.tcp_pose(home).position[2] > six_joint_arm.result.workspace.table_z_m + 0.05


def test_the_workspace_holds_the_whole_reach_with_the_table_as_its_floor(six_joint_arm: InitRun) -> None:
    robot = six_joint_arm.result.runtime.robot
    workspace = six_joint_arm.result.workspace
    rng = np.random.default_rng(1)
    qs = robot.lower + rng.random((500, robot.nq)) * (robot.upper - robot.lower)
    tcp = robot.tcp_points(qs)
    assert np.all(tcp[:, :2] > workspace.box_min[:2]) and np.all(tcp < workspace.box_max)
    assert workspace.table_z_m == 0.0


def test_every_joint_gets_a_provisional_contact_limit_from_its_effort_limit(six_joint_arm: InitRun) -> None:
    """An arm without a force/torque sensor is monitored from its motors' torques out of the box."""
    policy = six_joint_arm.result.runtime.policy
    section = policy.force.joint_torques
    assert section is not None and tuple(section.max_external_torque_nm) == policy.robot.joint_names
    model = six_joint_arm.result.runtime.robot.model
    for name, limit in section.max_external_torque_nm.items():
        effort = float(model.effortLimit[model.joints[model.getJointId(name)].idx_v])
        assert limit == pytest.approx(min(30.0, max(2.0, 0.15 * effort)), abs=0.05)


def test_a_picture_of_the_arm_at_home_is_written(six_joint_arm: InitRun) -> None:
    picture = six_joint_arm.result.picture_path
    assert picture is not None and picture.read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


def test_a_second_run_on_the_same_input_writes_the_same_bytes(six_joint_arm: InitRun, tmp_path: Path) -> None:
    first = six_joint_arm.options
    shutil.copytree(first.description.parent, tmp_path / "arm")  # the same layout elsewhere
    again = InitOptions(description=tmp_path / "arm" / first.description.name, output=tmp_path / "policy" / "arm.yaml",
                        fit=QUICK_FIT)
    run_init(again)
    for made, remade in ((first.output, again.output), (first.fitted_path, again.fitted_path),
                         (first.picture_path, again.picture_path)):
        assert made.read_bytes() == remade.read_bytes(), made.name


def test_fingers_on_prismatic_joints_get_a_gripper_section(arm_with_fingers: InitRun) -> None:
    policy = arm_with_fingers.result.runtime.policy
    assert policy.gripper is not None and "gripper" in policy.tools.enabled
    assert policy.gripper.max_width_m == pytest.approx(0.08)
    assert policy.robot.joint_names == arm_with_fingers.arm.joint_names  # the fingers are not arm joints


def test_an_arm_without_collision_geometry_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=3, n_joints=4, meshes=False)
    output = tmp_path / "policy.yaml"
    with pytest.raises(RobotModelError, match="no collision geometry"):
        run_init(InitOptions(description=arm.urdf, output=output, fit=QUICK_FIT))
    assert list(tmp_path.glob("policy*")) == []


def test_the_cli_prints_a_summary_and_names_the_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=4, n_joints=4)
    output = tmp_path / "cell.yaml"
    assert main(["init", str(arm.urdf), "--output", str(output), "--max-bodies", "1"]) == 0
    out = capsys.readouterr().out
    assert "robot " in out and "home: [" in out and str(output) in out
    assert load_policy(output).robot.joint_names == arm.joint_names


def test_an_unknown_joint_choice_is_refused_with_the_valid_ones(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=4, n_joints=4)
    assert main(["init", str(arm.urdf), "--output", str(tmp_path / "p.yaml"), "--joints", "nope,joint2"]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and arm.joint_names[0] in err
    assert not (tmp_path / "p.yaml").exists()


def test_the_policy_needs_no_meshes_at_run_time(tmp_path: Path) -> None:
    run = init_arm(tmp_path, seed=12, n_joints=4)
    shutil.rmtree(run.arm.urdf.parent / "meshes")
    robot = RobotModel.from_description(str(run.arm.urdf), run.arm.joint_names, "base_link", "tool0",
                                        collision_geometry=str(run.options.fitted_path))
    assert robot.fitted is not None and len(robot.capsules) >= 4


def test_reusing_the_fitted_file_writes_the_same_policy_without_fitting(six_joint_arm: InitRun, tmp_path: Path) -> None:
    first = six_joint_arm.options
    shutil.copytree(first.description.parent, tmp_path / "arm")
    again = InitOptions(description=tmp_path / "arm" / first.description.name, output=tmp_path / "policy" / "arm.yaml",
                        fit=QUICK_FIT, fitted=first.fitted_path)
    run_init(again)
    assert again.output.read_bytes() == first.output.read_bytes()
    assert again.fitted_path.read_bytes() == first.fitted_path.read_bytes()


def test_a_fitted_file_made_for_another_description_is_refused(six_joint_arm: InitRun, tmp_path: Path) -> None:
    other = write_random_arm(tmp_path / "other", seed=21, n_joints=6)
    with pytest.raises(RobotModelError, match="fitted to another description"):
        run_init(InitOptions(description=other.urdf, output=tmp_path / "p.yaml", fitted=six_joint_arm.options.fitted_path))
    assert not (tmp_path / "p.yaml").exists()


def test_a_finger_gets_one_capsule_per_part_so_it_lies_along_the_closing_plane(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=11, n_joints=5, gripper=True)
    description = load_description(arm.urdf)
    fingers = finger_links(description.model, arm.joint_names)
    assert fingers == {"finger1", "finger2"}
    finger = {"finger1": link_meshes(description)["finger1"]}
    assert len(fit_links(finger, FitSettings())["finger1"].bodies) > 1  # free, the fit would split it
    assert len(fit_links(finger, FitSettings(), fingers=fingers)["finger1"].bodies) == 1
