"""The random-arm generator other tests build on: reproducible, within its stated ranges, and
loadable by both Pinocchio and MuJoCo."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import pytest

from tests.robot.generated_arm import write_mjcf_twin, write_random_arm


def test_the_same_seed_writes_the_same_bytes(tmp_path: Path) -> None:
    first = write_random_arm(tmp_path / "a", seed=21, gripper=True)
    second = write_random_arm(tmp_path / "b", seed=21, gripper=True)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert files and all((tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes() for f in files)
    assert first.joint_names == second.joint_names


def test_the_joint_count_comes_from_the_seed_within_four_to_seven(tmp_path: Path) -> None:
    counts = {len(write_random_arm(tmp_path / str(seed), seed=seed, meshes=False).joint_names) for seed in range(12)}
    assert counts <= {4, 5, 6, 7} and len(counts) > 1


def test_limits_and_meshes_stay_within_the_stated_ranges(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=5, n_joints=7, gripper=True)
    root = ET.parse(arm.urdf).getroot()
    for joint in root.iter("joint"):
        if joint.get("name") in arm.joint_names:
            limit = joint.find("limit")
            assert limit is not None
            upper, velocity, effort = (float(limit.get(k, "nan")) for k in ("upper", "velocity", "effort"))
            assert 1.5 <= upper <= 2.9 and float(limit.get("lower", "nan")) == -upper
            assert 1.0 <= velocity <= 3.0 and 10.0 <= effort <= 150.0
    stls = list((tmp_path / "meshes").glob("*.stl"))
    assert len(stls) == 7 + 1 + 3  # base, links, hand, two fingers
    assert all(int.from_bytes(p.read_bytes()[80:84], "little") <= 64 for p in stls)


def test_mujoco_accepts_the_urdf_and_its_mjcf_twin(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=6, n_joints=6, gripper=True)
    from_urdf = mujoco.MjModel.from_xml_path(str(arm.urdf))
    twin = mujoco.MjModel.from_xml_path(str(write_mjcf_twin(arm, tmp_path / "twin")))
    assert from_urdf.njnt == twin.njnt == 8
    assert twin.nmesh == 10


def test_package_uris_put_the_meshes_under_the_package_folder(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=7, n_joints=4, package_uris=True)
    assert "package://generated_arm/meshes/link1.stl" in arm.urdf.read_text(encoding="utf-8")
    assert (arm.mesh_dir / "generated_arm" / "meshes" / "link1.stl").is_file()
    assert arm.urdf.parent != arm.mesh_dir


@pytest.mark.parametrize("n_joints", [3, 8])
def test_a_joint_count_outside_four_to_seven_is_refused(tmp_path: Path, n_joints: int) -> None:
    with pytest.raises(ValueError, match="4 to 7"):
        write_random_arm(tmp_path, seed=1, n_joints=n_joints)
