"""The compiled forward kinematics against Pinocchio: the bundled FR3 and generated serial arms.

`BatchFK` reads a Pinocchio model into a chain description and evaluates it with numba; here it
must equal Pinocchio's `forwardKinematics` + `updateFramePlacements` to 1e-12 on random
configurations within the limits, batched must equal single, and every joint type it does not
evaluate must be refused by name.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armwarden.core.errors import RobotModelError
from armwarden.robot import RobotModel
from armwarden.robot.batch_fk import BatchFK, JointKind, KinematicChain
from tests.helpers import SRC, child_env

TOLERANCE = 1e-12
N_CONFIGURATIONS = 500


def _random_configurations(model: pin.Model, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(model.lowerPositionLimit, model.upperPositionLimit, size=(n, model.nq))


def _assert_equal_to_pinocchio(model: pin.Model, fk: BatchFK, qs: np.ndarray, base_from_world: pin.SE3 | None = None) -> None:
    """Every joint pose and every frame of interest of `fk` against Pinocchio's, for each row of `qs`."""
    data = model.createData()
    frame_ids = [model.getFrameId(name) for name in fk.frame_names]
    base = np.eye(4) if base_from_world is None else base_from_world.homogeneous
    expected = np.empty((len(qs), fk.n_nodes, 4, 4))
    for n, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        expected[n, : fk.n_joints] = [data.oMi[j].homogeneous for j in range(model.njoints)]
        expected[n, fk.n_joints :] = [data.oMf[f].homogeneous for f in frame_ids]
    expected = base @ expected
    error = np.abs(fk.poses_batch(qs) - expected)
    n, k = np.unravel_index(np.argmax(error.max(axis=(2, 3))), error.shape[:2])
    names = [*model.names, *fk.frame_names]
    assert error.max() <= TOLERANCE, f"{names[k]} is off by {error.max():.3g} at q={qs[n].tolist()}"


# ---------------------------------------------------------------------------------------- the FR3
def test_fr3_collision_frames_and_tcp_equal_pinocchio_on_random_configurations(robot: RobotModel) -> None:
    carrying = list(dict.fromkeys(capsule.link for capsule in robot.capsules))  # the fitted bodies' links
    assert len(carrying) >= 8  # links 0–7 and the hand at least: the check covers the arm, not one link
    fk = BatchFK.from_model(robot.model, [*carrying, robot.tcp_frame])
    _assert_equal_to_pinocchio(robot.model, fk, _random_configurations(robot.model, N_CONFIGURATIONS, seed=25))


def test_fr3_for_robot_gives_every_moving_collision_link_and_the_tcp_in_the_base_frame(robot: RobotModel) -> None:
    fk = BatchFK.for_robot(robot)
    assert fk.frame_names == (*robot.moving_links_with_geometry(), robot.tcp_frame)
    qs = _random_configurations(robot.model, 50, seed=26)
    poses = fk.frame_poses_batch(qs)
    for n, q in enumerate(qs):
        for f, name in enumerate(fk.frame_names):
            expected = robot.frame_pose(q, name)
            np.testing.assert_allclose(poses[n, f, :3, :3], expected.rotation, rtol=0, atol=TOLERANCE)
            np.testing.assert_allclose(poses[n, f, :3, 3], expected.position, rtol=0, atol=TOLERANCE)


def test_a_base_frame_off_the_world_origin_is_applied_to_every_pose(robot: RobotModel) -> None:
    base_from_world = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 1.1), np.array([0.4, -0.1, 0.25]))
    fk = BatchFK.from_model(robot.model, [robot.tcp_frame, "fr3_link4"], base_from_world)
    _assert_equal_to_pinocchio(robot.model, fk, _random_configurations(robot.model, 50, seed=27), base_from_world)


def test_fr3_batched_poses_equal_single_configuration_poses(robot: RobotModel) -> None:
    fk = BatchFK.for_robot(robot)
    qs = _random_configurations(robot.model, 64, seed=28)
    batched = fk.poses_batch(qs)
    for n, q in enumerate(qs):
        np.testing.assert_array_equal(batched[n], fk.poses(q))
        np.testing.assert_array_equal(batched[n, fk.n_joints:], fk.frame_poses(q))
        np.testing.assert_array_equal(batched[n, :fk.n_joints], fk.joint_poses(q))


# ------------------------------------------------------------------------------ generated serial arms
@dataclass(frozen=True)
class GeneratedJoint:
    kind: str  # "revolute" or "prismatic"
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float
    upper: float


def _urdf(joints: list[GeneratedJoint], tool_xyz: tuple[float, float, float], tool_rpy: tuple[float, float, float]) -> str:
    def vec(values: tuple[float, float, float]) -> str:
        return " ".join(repr(float(v)) for v in values)

    links = "".join(f'<link name="link{i}"/>' for i in range(len(joints) + 1)) + '<link name="tool"/>'
    body = "".join(
        f'<joint name="joint{i + 1}" type="{joint.kind}"><parent link="link{i}"/><child link="link{i + 1}"/>'
        f'<origin xyz="{vec(joint.xyz)}" rpy="{vec(joint.rpy)}"/><axis xyz="{vec(joint.axis)}"/>'
        f'<limit lower="{joint.lower!r}" upper="{joint.upper!r}" effort="10" velocity="1"/></joint>'
        for i, joint in enumerate(joints)
    )
    tool = (
        f'<joint name="tool_joint" type="fixed"><parent link="link{len(joints)}"/><child link="tool"/>'
        f'<origin xyz="{vec(tool_xyz)}" rpy="{vec(tool_rpy)}"/></joint>'
    )
    return f'<?xml version="1.0"?><robot name="generated">{links}{body}{tool}</robot>'


def _load(tmp_path: Path, urdf: str, *, mimic: bool = False) -> pin.Model:
    path = tmp_path / "generated.urdf"
    path.write_text(urdf)
    return pin.buildModelFromUrdf(str(path), mimic)


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    return float(values[0]), float(values[1]), float(values[2])


_coordinate = st.floats(-0.3, 0.3, allow_nan=False)
_angle = st.floats(-np.pi, np.pi, allow_nan=False)
_aligned_axis = st.sampled_from([(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0), (0.0, 0.0, -1.0)])
_unaligned_axis = (
    st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3)
    .filter(lambda v: np.linalg.norm(v) > 0.1 and np.count_nonzero(v) >= 2)
    .map(lambda v: _triple(np.asarray(v) / np.linalg.norm(v)))
)


@st.composite
def _joints(draw: st.DrawFn, kinds: st.SearchStrategy[str]) -> GeneratedJoint:
    lower = draw(st.floats(-3.0, -0.1))
    return GeneratedJoint(
        kind=draw(kinds),
        xyz=draw(st.tuples(_coordinate, _coordinate, _coordinate)),
        rpy=draw(st.tuples(_angle, _angle, _angle)),
        axis=draw(st.one_of(_aligned_axis, _unaligned_axis)),
        lower=lower,
        upper=draw(st.floats(0.1, 3.0)),
    )


_revolute_arms = st.lists(_joints(st.just("revolute")), min_size=4, max_size=7)
_mixed_arms = st.lists(_joints(st.sampled_from(["revolute", "revolute", "prismatic"])), min_size=4, max_size=7)
_tool = st.tuples(st.tuples(_coordinate, _coordinate, _coordinate), st.tuples(_angle, _angle, _angle))


def _every_frame(model: pin.Model) -> list[str]:
    return [frame.name for frame in model.frames]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(joints=_revolute_arms, tool=_tool)
def test_generated_revolute_arm_equals_pinocchio_on_random_configurations(
    tmp_path: Path, joints: list[GeneratedJoint], tool: tuple
) -> None:
    model = _load(tmp_path, _urdf(joints, *tool))
    fk = BatchFK.from_model(model, _every_frame(model))
    _assert_equal_to_pinocchio(model, fk, _random_configurations(model, N_CONFIGURATIONS, seed=len(joints)))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(joints=_mixed_arms, tool=_tool)
def test_generated_arm_with_prismatic_joints_equals_pinocchio(tmp_path: Path, joints: list[GeneratedJoint], tool: tuple) -> None:
    model = _load(tmp_path, _urdf(joints, *tool))
    fk = BatchFK.from_model(model, _every_frame(model))
    _assert_equal_to_pinocchio(model, fk, _random_configurations(model, 100, seed=len(joints)))


def _one_of_each_kind() -> list[GeneratedJoint]:
    """A chain through every kernel branch: revolute about x, y, z and an unaligned axis, prismatic
    along an axis and along an unaligned direction (the property above draws them at random)."""
    axes = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.6, 0.8), (1.0, 0.0, 0.0), (0.48, 0.6, 0.64)]
    kinds = ["revolute"] * 4 + ["prismatic"] * 2
    rng = np.random.default_rng(6)
    return [
        GeneratedJoint(kind, _triple(rng.uniform(-0.3, 0.3, 3)), _triple(rng.uniform(-np.pi, np.pi, 3)), axis, -2.0, 2.0)
        for kind, axis in zip(kinds, axes, strict=True)
    ]


def test_a_chain_through_every_supported_joint_type_equals_pinocchio(tmp_path: Path) -> None:
    model = _load(tmp_path, _urdf(_one_of_each_kind(), (0.1, 0.0, 0.05), (0.0, 0.5, 0.0)))
    fk = BatchFK.from_model(model, _every_frame(model))
    kinds = set(fk.chain.kinds[1:].tolist())
    assert kinds == {JointKind.REVOLUTE_X, JointKind.REVOLUTE_Y, JointKind.REVOLUTE_Z, JointKind.REVOLUTE_AXIS, JointKind.PRISMATIC}
    _assert_equal_to_pinocchio(model, fk, _random_configurations(model, N_CONFIGURATIONS, seed=7))


def test_generated_arm_batched_poses_equal_single_configuration_poses(tmp_path: Path) -> None:
    model = _load(tmp_path, _urdf(_one_of_each_kind(), (0.1, 0.0, 0.05), (0.0, 0.5, 0.0)))
    fk = BatchFK.from_model(model, _every_frame(model))
    qs = _random_configurations(model, 64, seed=8)
    batched = fk.poses_batch(qs)
    for n, q in enumerate(qs):
        np.testing.assert_array_equal(batched[n], fk.poses(q))


# ------------------------------------------------------------------------------ refusals
def _chain_urdf(second_joint: str) -> str:
    return (
        '<?xml version="1.0"?><robot name="r"><link name="base"/><link name="a"/><link name="b"/>'
        '<joint name="first" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        f"{second_joint}</robot>"
    )


@pytest.mark.parametrize(
    ("joint", "kind"),
    [
        ('<joint name="hover" type="floating"><parent link="a"/><child link="b"/></joint>', "JointModelFreeFlyer"),
        ('<joint name="hover" type="planar"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint>', "JointModelPlanar"),
        ('<joint name="hover" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint>', "JointModelRUBZ"),
    ],
    ids=["free-flyer", "planar", "continuous"],
)
def test_unsupported_joint_types_are_refused_by_name(tmp_path: Path, joint: str, kind: str) -> None:
    model = _load(tmp_path, _chain_urdf(joint))
    with pytest.raises(RobotModelError, match=rf"joint 'hover' is a {kind}"):
        KinematicChain.from_model(model, [])


def test_a_spherical_joint_is_refused_by_name() -> None:
    model = pin.Model()
    first = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "first")
    model.addJoint(first, pin.JointModelSpherical(), pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3])), "wrist_ball")
    with pytest.raises(RobotModelError, match=r"joint 'wrist_ball' is a JointModelSpherical"):
        BatchFK.from_model(model, [])


def test_a_mimic_joint_is_refused_by_name(tmp_path: Path) -> None:
    mimic = (
        '<joint name="follower" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
        '<mimic joint="first" multiplier="-1" offset="0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
    )
    model = _load(tmp_path, _chain_urdf(mimic), mimic=True)
    with pytest.raises(RobotModelError, match=r"joint 'follower' is a JointModelMimic"):
        BatchFK.from_model(model, [])


def test_an_unknown_frame_is_refused_with_the_valid_names(robot: RobotModel) -> None:
    with pytest.raises(RobotModelError, match=r"unknown frame 'fr3_link9'; valid frames: .*fr3_hand_tcp"):
        BatchFK.from_model(robot.model, ["fr3_link9"])


def test_a_non_finite_configuration_is_refused(robot: RobotModel) -> None:
    fk = BatchFK.for_robot(robot)
    q = np.zeros(robot.nq)
    q[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        fk.poses(q)
    qs = np.zeros((5, robot.nq))
    qs[2, 6] = np.inf
    with pytest.raises(ValueError, match="configuration 2 of the batch holds a non-finite value"):
        fk.poses_batch(qs)


def test_a_configuration_of_the_wrong_length_is_refused(robot: RobotModel) -> None:
    fk = BatchFK.for_robot(robot)
    with pytest.raises(ValueError, match="a configuration has 7 values"):
        fk.poses(np.zeros(6))
    with pytest.raises(ValueError, match=r"shape \(N, 7\)"):
        fk.poses_batch(np.zeros((4, 8)))


def test_an_output_array_of_the_wrong_shape_is_refused(robot: RobotModel) -> None:
    fk = BatchFK.for_robot(robot)
    with pytest.raises(ValueError, match="out must have shape"):
        fk.poses(np.zeros(robot.nq), out=np.empty((fk.n_nodes - 1, 4, 4)))
    with pytest.raises(ValueError, match="out must have shape"):
        fk.poses_batch(np.zeros((3, robot.nq)), out=np.empty((2, fk.n_nodes, 4, 4)))


def test_inputs_of_other_types_and_layouts_are_converted(robot: RobotModel) -> None:
    fk = BatchFK.for_robot(robot)
    qs = _random_configurations(robot.model, 4, seed=9)
    expected = fk.poses_batch(qs)
    read_only = qs.copy()
    read_only.flags.writeable = False
    np.testing.assert_array_equal(fk.poses_batch(read_only), expected)
    np.testing.assert_array_equal(fk.poses_batch(np.asfortranarray(qs)), expected)
    np.testing.assert_array_equal(fk.poses(qs[1].tolist()), expected[1])
    np.testing.assert_array_equal(fk.poses(qs[:, ::-1][2, ::-1]), expected[2])  # a strided view


# ------------------------------------------------------------------------------ the compile cache
def test_fk_works_without_any_writable_cache_directory(tmp_path: Path) -> None:
    """A copy of the module whose `__pycache__` cannot be a directory, with numba's user and
    configured cache directories below a regular file: numba has nowhere to cache (it would
    raise at import), so the kernels are compiled in memory, a warning says so, and FK is exact."""
    package = tmp_path / "copy"
    package.mkdir()
    (package / "batch_fk.py").write_text((SRC / "armwarden" / "robot" / "batch_fk.py").read_text())
    (package / "__pycache__").write_text("a file where numba wants its in-tree cache directory")
    blocker = tmp_path / "not-a-directory"
    blocker.write_text("")
    script = textwrap.dedent(
        f"""
        import importlib.util, sys
        import numpy as np, pinocchio as pin
        spec = importlib.util.spec_from_file_location("batch_fk_copy", {str(package / "batch_fk.py")!r})
        module = sys.modules["batch_fk_copy"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        model = pin.Model()
        first = model.addJoint(0, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3])), "first")
        model.addJoint(first, pin.JointModelRevoluteUnaligned(0.0, 0.6, 0.8), pin.SE3(np.eye(3), np.array([0.2, 0.0, 0.0])), "second")
        fk = module.BatchFK.from_model(model, [])
        q = np.array([0.4, -1.1])
        data = model.createData()
        pin.forwardKinematics(model, data, q)
        error = np.abs(fk.joint_poses(q)[2] - data.oMi[2].homogeneous).max()
        print("cached", module.kernels_cached(), "error", error)
        sys.exit(0 if error <= 1e-12 else 1)
        """
    )
    env = {**child_env(), "NUMBA_CACHE_DIR": str(blocker / "numba"), "XDG_CACHE_HOME": str(blocker / "xdg"),
           "HOME": str(blocker / "home")}
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "cached False" in result.stdout
    assert "cannot cache" in result.stderr


def test_compiled_kernels_are_cached_on_disk_and_loaded_by_the_next_process(tmp_path: Path) -> None:
    """With a writable cache directory the first import compiles and writes the machine code;
    the next process loads it (numba counts a cache hit) instead of compiling again."""
    script = textwrap.dedent(
        """
        from armwarden.robot import batch_fk
        print("cached", batch_fk.kernels_cached(), "hits", sum(batch_fk.fk_into.stats.cache_hits.values()),
              sum(batch_fk.fk_batch_into.stats.cache_hits.values()))
        """
    )
    env = {**child_env(), "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    first = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    assert first.stdout.split() == ["cached", "True", "hits", "0", "0"]
    assert list((tmp_path / "numba-cache").rglob("*.nbi"))
    second = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0, second.stderr
    assert second.stdout.split() == ["cached", "True", "hits", "1", "1"]
