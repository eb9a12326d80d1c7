"""Convert a bundled arm's source description (MuJoCo Menagerie MJCF) into ArmWarden's own URDF.

    .venv/bin/python scripts/convert_description.py ARM --source FILE [--out FILE] [--check]

ARM is one of the recipes below (ur5e, gen3, xarm7, so101, piper); FILE is the arm's MJCF as
its SOURCES.md names it (kept outside the repository; mesh files need not exist: mesh geoms are
dropped before MuJoCo compiles the model, collision meshes become `package://` references).
The output (by default src/armwarden/robots/ARM/description.urdf) has the source's links, joints
(origin, axis, limits), inertials (mass, centre of mass, full inertia tensor) and collision
primitives (a capsule becomes a cylinder and two spheres), a fixed TCP frame, and no visuals.

Why our own converter: the bundled descriptions must be reproducible from a named source commit,
carry only what ArmWarden reads, and be checked: before writing, Pinocchio's forward kinematics of
the URDF must equal MuJoCo's of the source (every moving joint, the same TCP point) to 1e-9 m over
200 random configurations. `--check` exits 1 if the file on disk differs. A dev tool: nothing
runs it at run time. Same source, same bytes.
"""

# pyright: reportAttributeAccessIssue=false
from __future__ import annotations

import argparse
import math
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

ROBOTS = Path(__file__).resolve().parent.parent / "src" / "armwarden" / "robots"
TOLERANCE_M = 1e-9
SAMPLES = 200
SEED = 20261128


@dataclass(frozen=True)
class Recipe:
    """What the source lacks or we decide: the TCP, the datasheet limits, the joints kept fixed."""

    name: str
    title: str
    tcp_parent: str
    tcp_name: str
    tcp_xyz: tuple[float, float, float]
    tcp_rpy: tuple[float, float, float]
    velocity: dict[str, float]
    """rad/s (m/s for a slide joint), from the manufacturer's datasheet (SOURCES.md)"""
    effort: dict[str, float] = field(default_factory=dict)
    """N·m (N), where the source has no actuator force range for the joint"""
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    """rad, for joints the source leaves unlimited (continuous)"""
    frozen: tuple[str, ...] = ()
    """joints made fixed at 0 (a closed linkage URDF cannot express)"""
    mesh_suffix: str | None = None
    mesh_names: dict[str, str] = field(default_factory=dict)
    """the manufacturer's file for a source mesh file whose name differs beyond the suffix"""
    """the manufacturer's file suffix for the source's collision meshes (e.g. `.STL`), if it differs"""
    notes: tuple[str, ...] = ()


_TWO_PI = 2.0 * math.pi
_UR_SPEED = math.pi  # UR5e datasheet: every joint 180 deg/s
_GEN3_LARGE, _GEN3_SMALL = math.radians(80.0), math.radians(70.0)  # Kinova's ros2_kortex URDF: max joint speed
_XARM_SPEED = math.pi  # UFACTORY xArm7 datasheet: max joint speed 180 deg/s
_STS3215_SPEED = math.radians(60.0) / 0.222  # Feetech STS3215 no-load speed as published (0.222 s/60 deg, 7.4 V)

RECIPES: dict[str, Recipe] = {
    "ur5e": Recipe(
        name="ur5e", title="Universal Robots UR5e",
        # the tool flange: 0.1 m out along wrist 3's axis (the end of the source's flange cylinder),
        # z out of the flange as UR's tool0
        tcp_parent="wrist_3_link", tcp_name="tool0", tcp_xyz=(0.0, 0.1, 0.0), tcp_rpy=(-math.pi / 2, 0.0, 0.0),
        velocity=dict.fromkeys(("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
                                "wrist_2_joint", "wrist_3_joint"), _UR_SPEED),
    ),
    "gen3": Recipe(
        name="gen3", title="Kinova Gen3 (7 joints, vision module, no gripper)",
        # the source's pinch site: the bracelet's tool interface, z out of the flange
        tcp_parent="bracelet_link", tcp_name="tool_frame", tcp_xyz=(0.0, 0.0, -0.061525),
        tcp_rpy=(math.pi, 0.0, 0.0),
        velocity={"joint_1": _GEN3_LARGE, "joint_2": _GEN3_LARGE, "joint_3": _GEN3_LARGE, "joint_4": _GEN3_LARGE,
                  "joint_5": _GEN3_SMALL, "joint_6": _GEN3_SMALL, "joint_7": _GEN3_SMALL},
        # ros2_kortex's URDF (kortex_description/arms/gen3/7dof/urdf/gen3_macro.xacro): continuous torque
        effort={"joint_1": 39.0, "joint_2": 39.0, "joint_3": 39.0, "joint_4": 39.0,
                "joint_5": 9.0, "joint_6": 9.0, "joint_7": 9.0},
        mesh_suffix=".STL",
        # joints 1, 3, 5, 7 turn without end; one turn either way, as ros2_kortex with an external cable
        ranges=dict.fromkeys(("joint_1", "joint_3", "joint_5", "joint_7"), (-_TWO_PI, _TWO_PI)),
    ),
    "xarm7": Recipe(
        name="xarm7", title="UFACTORY xArm7 with the xArm Gripper",
        tcp_parent="xarm_gripper_base_link", tcp_name="link_tcp", tcp_xyz=(0.0, 0.0, 0.172), tcp_rpy=(0.0, 0.0, 0.0),
        velocity={f"joint{index}": _XARM_SPEED for index in range(1, 8)},
        mesh_suffix=".STL", mesh_names={"end_tool.stl": "link7.STL"},
        # the gripper's six-bar linkage (a closed chain in the source) is held open: fixed links at 0
        frozen=("left_driver_joint", "left_finger_joint", "left_inner_knuckle_joint",
                "right_driver_joint", "right_finger_joint", "right_inner_knuckle_joint"),
    ),
    "so101": Recipe(
        name="so101", title="SO-ARM101 (TheRobotStudio, Hugging Face LeRobot)",
        # the source's gripperframe site: between the jaws' tips
        tcp_parent="gripper", tcp_name="gripperframe", tcp_xyz=(0.012, -0.000218, -0.098127),
        tcp_rpy=(0.0, math.pi / 2, 0.0),
        velocity=dict.fromkeys(("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"), _STS3215_SPEED),
    ),
    "piper": Recipe(
        name="piper", title="AgileX PiPER with its parallel gripper",
        # on link 6's axis at the middle of the finger pads (the source's finger boxes span 0.080-0.140 m)
        tcp_parent="link6", tcp_name="tcp", tcp_xyz=(0.0, 0.0, 0.11003), tcp_rpy=(0.0, 0.0, 0.0),
        # piper_sdk: joint speed limit 3.0 rad/s, MIT-mode torque limit 8 N·m, gripper effort 0-5
        velocity={**dict.fromkeys((f"joint{index}" for index in range(1, 7)), 3.0), "joint7": 0.1, "joint8": 0.1},
        effort={**dict.fromkeys((f"joint{index}" for index in range(1, 7)), 8.0), "joint7": 5.0, "joint8": 5.0},
        # the narrower of the source's range and piper_sdk's joint limits; the fingers: the small gripper's
        # 70 mm stroke (piper_sdk), each finger opening outwards from closed (the source lets them cross)
        ranges={"joint1": (-2.6179, 2.6179), "joint4": (-1.745, 1.745), "joint6": (-2.09439, 2.09439),
                "joint7": (0.0, 0.035), "joint8": (-0.035, 0.0)},
    ),
}


# ---------------------------------------------------------------- reading the source

@dataclass(frozen=True)
class MeshRef:
    body: str
    file: str
    pos: np.ndarray
    quat: np.ndarray


def load_source(path: Path, recipe: Recipe) -> tuple[mujoco.MjModel, list[MeshRef]]:
    """The source compiled without its meshes, and its collision mesh geoms (body frame)."""
    spec = mujoco.MjSpec.from_file(str(path))
    files = {mesh.name: Path(mesh.file).name for mesh in spec.meshes}
    meshes: list[MeshRef] = []
    for geom in list(spec.geoms):
        if geom.type != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        if geom.contype or geom.conaffinity:
            body = geom.parent.name
            file = files[geom.meshname]
            if file in recipe.mesh_names:
                file = recipe.mesh_names[file]
            elif recipe.mesh_suffix:
                file = str(Path(file).with_suffix(recipe.mesh_suffix))
            meshes.append(MeshRef(body, file, np.array(geom.pos, float), np.array(geom.quat, float)))
        spec.delete(geom)
    for mesh in list(spec.meshes):
        spec.delete(mesh)
    model = spec.compile()
    return model, meshes


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int) -> str:
    name = mujoco.mj_id2name(model, kind, index)
    if not name:
        raise SystemExit(f"an unnamed {kind.name} (#{index}) in the source: every body and joint needs a name")
    return name


# ---------------------------------------------------------------- writing the URDF

def _num(value: float) -> str:
    """15 significant digits (drops float noise such as 0.019999999999999997); tiny values as 0."""
    value = float(value)
    return "0" if abs(value) < 1e-15 else f"{value:.15g}"


def _vec(values: np.ndarray | tuple[float, ...]) -> str:
    return " ".join(_num(value) for value in values)


def _rpy(quat: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (R = Rz(y) Ry(p) Rx(r)) of a MuJoCo quaternion (w x y z)."""
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, np.asarray(quat, float) / np.linalg.norm(quat))
    return np.asarray(pin.rpy.matrixToRpy(rotation.reshape(3, 3)), float)


def _origin(pos: np.ndarray, quat: np.ndarray) -> str:
    return f'<origin xyz="{_vec(pos)}" rpy="{_vec(_rpy(quat))}"/>'


def _inertial(model: mujoco.MjModel, body: int) -> str:
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.body_iquat[body])
    rot = rotation.reshape(3, 3)
    tensor = rot @ np.diag(model.body_inertia[body]) @ rot.T
    ixx, ixy, ixz, iyy, iyz, izz = tensor[0, 0], tensor[0, 1], tensor[0, 2], tensor[1, 1], tensor[1, 2], tensor[2, 2]
    return (f'    <inertial><origin xyz="{_vec(model.body_ipos[body])}" rpy="0 0 0"/>'
            f'<mass value="{_num(model.body_mass[body])}"/>\n'
            f'      <inertia ixx="{_num(ixx)}" ixy="{_num(ixy)}" ixz="{_num(ixz)}" iyy="{_num(iyy)}" '
            f'iyz="{_num(iyz)}" izz="{_num(izz)}"/></inertial>')


def _collisions(model: mujoco.MjModel, body: int, body_name: str, meshes: list[MeshRef], package: str) -> list[str]:
    lines: list[str] = []
    for geom in range(model.ngeom):
        if model.geom_bodyid[geom] != body or not (model.geom_contype[geom] or model.geom_conaffinity[geom]):
            continue
        pos, quat, size = model.geom_pos[geom], model.geom_quat[geom], model.geom_size[geom]
        kind = mujoco.mjtGeom(int(model.geom_type[geom]))
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            shapes = [(pos, f'<box size="{_vec(2 * size)}"/>')]
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            shapes = [(pos, f'<sphere radius="{_num(size[0])}"/>')]
        elif kind in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE):
            shapes = [(pos, f'<cylinder radius="{_num(size[0])}" length="{_num(2 * size[1])}"/>')]
            if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                rotation = np.zeros(9)
                mujoco.mju_quat2Mat(rotation, quat)
                axis = rotation.reshape(3, 3)[:, 2] * size[1]
                shapes += [(pos + sign * axis, f'<sphere radius="{_num(size[0])}"/>') for sign in (1.0, -1.0)]
        else:
            raise SystemExit(f"{body_name}: collision geom type {kind} is not converted")
        lines += [f'    <collision>{_origin(centre, quat)}<geometry>{shape}</geometry></collision>'
                  for centre, shape in shapes]
    for mesh in meshes:
        if mesh.body == body_name:
            lines.append(f'    <collision>{_origin(mesh.pos, mesh.quat)}<geometry>'
                         f'<mesh filename="package://{package}/meshes/{mesh.file}"/></geometry></collision>')
    return lines


def _limits(model: mujoco.MjModel, joint: int, name: str, recipe: Recipe) -> tuple[float, float, float, float]:
    if name in recipe.ranges:
        lower, upper = recipe.ranges[name]
    elif model.jnt_limited[joint]:
        lower, upper = (float(value) for value in model.jnt_range[joint])
    else:
        raise SystemExit(f"joint {name} is unlimited in the source and the recipe gives no range")
    effort = recipe.effort.get(name)
    if effort is None:
        for actuator in range(model.nu):
            if (int(model.actuator_trntype[actuator]) == int(mujoco.mjtTrn.mjTRN_JOINT)
                    and model.actuator_trnid[actuator, 0] == joint and model.actuator_forcelimited[actuator]):
                effort = float(max(abs(value) for value in model.actuator_forcerange[actuator]))
    if effort is None:
        raise SystemExit(f"joint {name}: no actuator force range in the source and no effort in the recipe")
    if name not in recipe.velocity:
        raise SystemExit(f"joint {name}: the recipe gives no velocity limit")
    return lower, upper, effort, recipe.velocity[name]


def render(model: mujoco.MjModel, meshes: list[MeshRef], recipe: Recipe, header: str) -> str:
    """Our URDF of the compiled source."""
    package = f"{recipe.name}_description"
    roots = [body for body in range(1, model.nbody) if model.body_parentid[body] == 0]
    if len(roots) != 1:
        raise SystemExit("the source must have exactly one body under the world")
    lines = ['<?xml version="1.0"?>', "<!--", *(f"  {line}" if line else "" for line in header.splitlines()),
             "-->", f'<robot name="{recipe.name}">']
    for body in range(1, model.nbody):
        name = _name(model, mujoco.mjtObj.mjOBJ_BODY, body)
        if body != roots[0]:
            parent = _name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.body_parentid[body]))
            joints = [joint for joint in range(model.njnt) if model.jnt_bodyid[joint] == body]
            if len(joints) > 1:
                raise SystemExit(f"body {name} has {len(joints)} joints; one at most is converted")
            origin = _origin(model.body_pos[body], model.body_quat[body])
            if not joints or _name(model, mujoco.mjtObj.mjOBJ_JOINT, joints[0]) in recipe.frozen:
                lines.append(f'  <joint name="{parent}_to_{name}" type="fixed">\n    {origin}'
                             f'<parent link="{parent}"/><child link="{name}"/>\n  </joint>')
            else:
                joint = joints[0]
                joint_name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
                if np.any(model.jnt_pos[joint] != 0) or model.qpos0[model.jnt_qposadr[joint]] != 0:
                    raise SystemExit(f"joint {joint_name}: an offset anchor or reference is not converted")
                kinds = {int(mujoco.mjtJoint.mjJNT_HINGE): "revolute", int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic"}
                if int(model.jnt_type[joint]) not in kinds:
                    raise SystemExit(f"joint {joint_name}: only hinge and slide joints are converted")
                lower, upper, effort, velocity = _limits(model, joint, joint_name, recipe)
                lines.append(f'  <joint name="{joint_name}" type="{kinds[int(model.jnt_type[joint])]}">\n    {origin}'
                             f'<parent link="{parent}"/><child link="{name}"/>\n'
                             f'    <axis xyz="{_vec(model.jnt_axis[joint])}"/><limit lower="{_num(lower)}" '
                             f'upper="{_num(upper)}" effort="{_num(effort)}" velocity="{_num(velocity)}"/>\n  </joint>')
        lines.append(f'  <link name="{name}">')
        if model.body_mass[body] > 0:
            lines.append(_inertial(model, body))
        lines += _collisions(model, body, name, meshes, package)
        lines.append("  </link>")
    lines.append(f'  <joint name="{recipe.tcp_name}_joint" type="fixed">\n'
                 f'    <origin xyz="{_vec(recipe.tcp_xyz)}" rpy="{_vec(recipe.tcp_rpy)}"/>'
                 f'<parent link="{recipe.tcp_parent}"/><child link="{recipe.tcp_name}"/>\n  </joint>')
    lines += [f'  <link name="{recipe.tcp_name}"/>', "</robot>", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------- checking it

def moving_joints(model: mujoco.MjModel, recipe: Recipe) -> list[str]:
    return [name for joint in range(model.njnt)
            if (name := _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)) not in recipe.frozen]


def fk_disagreement(source: mujoco.MjModel, urdf: str, recipe: Recipe, samples: int = SAMPLES) -> float:
    """The largest distance [m] between Pinocchio's TCP of `urdf` and MuJoCo's of the source, in the
    root body's frame, over random configurations within the URDF's limits; the TCP's axes are
    compared too (a unit axis' error counted as metres at 1 m)."""
    model = pin.buildModelFromXML(urdf)
    data = model.createData()
    frame = model.getFrameId(recipe.tcp_name)
    root = next(body for body in range(1, source.nbody) if source.body_parentid[body] == 0)
    parent = mujoco.mj_name2id(source, mujoco.mjtObj.mjOBJ_BODY, recipe.tcp_parent)
    offset = pin.SE3(pin.rpy.rpyToMatrix(*recipe.tcp_rpy), np.array(recipe.tcp_xyz))
    joints = moving_joints(source, recipe)
    if sorted(joints) != sorted(model.names[1:]):
        raise SystemExit(f"joints differ: source {joints}, URDF {list(model.names[1:])}")
    mj_data = mujoco.MjData(source)
    rng = np.random.default_rng(SEED)
    worst = 0.0
    for _ in range(samples):
        q = rng.uniform(model.lowerPositionLimit, model.upperPositionLimit)
        mj_data.qpos[:] = source.qpos0
        for name in joints:
            joint = model.getJointId(name)
            mj_data.qpos[source.jnt_qposadr[mujoco.mj_name2id(source, mujoco.mjtObj.mjOBJ_JOINT, name)]] = \
                q[model.joints[joint].idx_q]
        mujoco.mj_kinematics(source, mj_data)
        pin.framesForwardKinematics(model, data, q)

        def pose(body: int) -> pin.SE3:
            return pin.SE3(mj_data.xmat[body].reshape(3, 3).copy(), mj_data.xpos[body].copy())

        expected = pose(root).inverse() * pose(parent) * offset
        got = data.oMf[frame]
        worst = max(worst, float(np.linalg.norm(expected.translation - got.translation)),
                    float(np.abs(expected.rotation - got.rotation).max()))
    return worst


def header_text(recipe: Recipe, source: Path) -> str:
    return "\n".join([
        f"{recipe.title}: ArmWarden's description, written by scripts/convert_description.py",
        f"from {source.name} (MuJoCo Menagerie; the commit, licence and our changes: SOURCES.md).",
        "Links and joints as the source's bodies and joints (the source's world placement of its root",
        "body dropped: the root link is the base frame); inertials as the source's; velocity limits from",
        "the manufacturer's datasheet; no visuals; collision: the source's primitives (a capsule as a",
        "cylinder and two spheres) and package:// references to its collision meshes, which are not",
        f"shipped (armwarden init finds {recipe.name}_description/meshes/ under a mesh path it is given).",
        f"TCP: {recipe.tcp_name}, fixed on {recipe.tcp_parent}.",
        *recipe.notes,
    ])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("arm", choices=sorted(RECIPES))
    parser.add_argument("--source", type=Path, required=True, help="the arm's MJCF (see its SOURCES.md)")
    parser.add_argument("--out", type=Path, help="default: src/armwarden/robots/ARM/description.urdf")
    parser.add_argument("--check", action="store_true", help="exit 1 if the output file would change")
    args = parser.parse_args(argv)
    recipe = RECIPES[args.arm]
    out = args.out or ROBOTS / recipe.name / "description.urdf"
    source, meshes = load_source(args.source, recipe)
    urdf = render(source, meshes, recipe, header_text(recipe, args.source))
    ET.fromstring(urdf)  # well-formed for strict parsers too (no "--" in a comment), not only Pinocchio's
    error = fk_disagreement(source, urdf, recipe)
    joints = moving_joints(source, recipe)
    print(f"{recipe.name}: {len(joints)} joints, {len(meshes)} collision meshes referenced; TCP agreement "
          f"Pinocchio(URDF) vs MuJoCo(source) over {SAMPLES} configurations: {error:.3g} m", file=sys.stderr)
    if error > TOLERANCE_M:
        print(f"{recipe.name}: disagreement {error:.3g} m exceeds {TOLERANCE_M} m; nothing written", file=sys.stderr)
        return 1
    if args.check:
        current = out.read_text(encoding="utf-8") if out.exists() else ""
        if current != urdf:
            print(f"{out} would change", file=sys.stderr)
            return 1
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(urdf, encoding="utf-8")
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
