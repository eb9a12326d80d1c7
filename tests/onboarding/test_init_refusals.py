"""What init refuses because the policy it would write would be less safe than it says (found by
an outside review, each with its reproducer): an MJCF that Pinocchio reads differently from MuJoCo
(a mesh scale from `<default>`, a body inside `<frame>`, a joint's `ref`), an output that is the
description itself, a reused fit whose meshes changed, a moving link with a visual shape but no
collision shape; and a cell's `world` root is not taken for the table."""

from __future__ import annotations

from pathlib import Path

import pytest

from armwarden.core.errors import RobotModelError
from armwarden.onboarding import InitOptions, run_init
from armwarden.onboarding.checks import refuse_mjcf_misread
from armwarden.robot.description_chain import infer_chain
from armwarden.robot.description_files import load_description
from armwarden.robot.link_meshes import link_meshes
from tests.onboarding.conftest import QUICK_FIT, InitRun
from tests.robot.generated_arm import box, write_random_arm, write_stl

ARM_TAIL = """<body name="l2" pos="0 0 0.3"><joint name="j2" axis="0 1 0" range="-1.5 1.5"/>
  <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.03"/>
  <body name="l3" pos="0 0 0.3"><joint name="j3" axis="0 1 0" range="-2 2"/>
   <geom type="capsule" fromto="0 0 0 0 0 0.2" size="0.03"/>
   <body name="l4" pos="0 0 0.2"><joint name="j4" axis="0 0 1" range="-3 3"/>
    <geom type="capsule" fromto="0 0 0 0 0 0.1" size="0.02"/><site name="tool0" pos="0 0 0.1"/>
   </body></body></body>"""


def mjcf(directory: Path, *, defaults: str = "", first: str = "", joint: str = 'range="-2 2"', wrap: bool = False) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "meshes").mkdir(exist_ok=True)
    write_stl(directory / "meshes" / "part.stl", *box((0.06, 0.06, 0.3), (0.0, 0.0, 0.15)))
    tail = f"<frame>{ARM_TAIL}</frame>" if wrap else ARM_TAIL
    path = directory / "arm.xml"
    path.write_text(f"""<mujoco model="t"><compiler angle="radian" meshdir="meshes"/>{defaults}
 <asset><mesh name="part" file="part.stl"/></asset>
 <worldbody><body name="base"><geom type="cylinder" size="0.06 0.04"/>
  <body name="l1" pos="0 0 0.05"><joint name="j1" axis="0 0 1" {joint}/><geom type="mesh" mesh="part"/>{first}
  {tail}</body></body></worldbody></mujoco>""", encoding="utf-8")
    return path


def check(path: Path) -> None:
    description = load_description(path)
    refuse_mjcf_misread(description, link_meshes(description))


def test_an_mjcf_that_pinocchio_and_mujoco_read_alike_passes(tmp_path: Path) -> None:
    check(mjcf(tmp_path))


def test_a_mesh_scale_set_in_the_mjcf_defaults_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RobotModelError, match=r"differently from MuJoCo.*body l1: collision extent"):
        check(mjcf(tmp_path, defaults='<default><mesh scale="2 2 2"/></default>'))


def test_bodies_inside_an_mjcf_frame_are_refused_not_dropped(tmp_path: Path) -> None:
    with pytest.raises(RobotModelError, match=r"lacks the bodies l2, l3, l4"):
        check(mjcf(tmp_path, wrap=True))


def test_an_mjcf_joint_ref_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RobotModelError, match=r"joint j1 has ref 0.5"):
        check(mjcf(tmp_path, joint='range="-2 2" ref="0.5"'))


def test_an_output_that_is_the_description_is_refused_and_the_description_kept(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=5, n_joints=4)
    before = arm.urdf.read_bytes()
    with pytest.raises(RobotModelError, match="is the description itself"):
        run_init(InitOptions(description=arm.urdf, output=arm.urdf, fit=QUICK_FIT))
    assert arm.urdf.read_bytes() == before


def test_a_reused_fit_whose_meshes_changed_is_refused(six_joint_arm: InitRun, tmp_path: Path) -> None:
    first = six_joint_arm.options
    arm = write_random_arm(tmp_path / "arm", seed=6, n_joints=6)  # the same arm, byte for byte
    write_stl(arm.urdf.parent / "meshes" / "link2.stl", *box((0.5, 0.5, 0.2), (0.0, 0.0, 0.1)))  # a bigger part
    with pytest.raises(RobotModelError, match=r"changed: link2"):
        run_init(InitOptions(description=arm.urdf, output=tmp_path / "policy" / "arm.yaml", fitted=first.fitted_path))
    assert not (tmp_path / "policy").exists()


def test_a_moving_link_with_a_visual_but_no_collision_shape_is_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=7, n_joints=4, meshes=False)
    text = arm.urdf.read_text(encoding="utf-8")
    for link in ("link1", "link2", "link3", "link4", "base_link"):  # every link its box, but link2 only a visual
        shape = '<geometry><box size="0.05 0.05 0.1"/></geometry>'
        element = "visual" if link == "link2" else "collision"
        text = text.replace(f'<link name="{link}">', f'<link name="{link}"><{element}>{shape}</{element}>')
    arm.urdf.write_text(text, encoding="utf-8")
    with pytest.raises(RobotModelError, match=r"moving link\(s\) link2 have a visual shape but no collision"):
        run_init(InitOptions(description=arm.urdf, output=tmp_path / "p.yaml", fit=QUICK_FIT))


def test_a_cell_world_root_is_not_taken_for_the_table(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=8, n_joints=4)
    text = arm.urdf.read_text(encoding="utf-8").replace(
        '<link name="base_link">', '<link name="world"/><joint name="mount" type="fixed"><parent link="world"/>'
        '<child link="base_link"/><origin xyz="0 0 0.8" rpy="0 0 0"/></joint><link name="base_link">')
    arm.urdf.write_text(text, encoding="utf-8")
    assert infer_chain(load_description(arm.urdf).model).base_frame == "base_link"
