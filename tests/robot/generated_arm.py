"""Random serial arms the project has never seen, written as a URDF with STL mesh links.

`write_random_arm(directory, seed)` writes an arm of 4–7 revolute joints standing up from
`base_link` (z up): joint axes alternating between the link's own axis and a horizontal one, with
small random tilts; link lengths 0.08–0.3 m; every link a small closed mesh (an octagonal prism,
16 faces around); physically valid inertials (MuJoCo accepts them); limits a real datasheet might
give; a fixed `tool0` beyond the last link; optionally a hand with two prismatic fingers (the second
`<mimic>`s the first). Meshes are referenced relative to the URDF or as
`package://generated_arm/meshes/...` (then the URDF sits in a folder of its own, so the meshes are
found only through the mesh path). Same seed, same bytes.
"""

from __future__ import annotations

import math
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

PACKAGE = "generated_arm"
SIDES = 8


@dataclass(frozen=True)
class GeneratedArm:
    urdf: Path
    mesh_dir: Path  # give as the mesh path (the package root when package URIs are used)
    joint_names: tuple[str, ...]
    base_frame: str
    tcp_frame: str
    gripper_joints: tuple[str, ...]


def prism(radius: float, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed octagonal prism around the z axis from z0 to z1, outward-wound."""
    angles = np.arange(SIDES) * 2.0 * math.pi / SIDES
    ring = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    vertices = np.vstack([np.column_stack([ring, np.full(SIDES, z0)]), np.column_stack([ring, np.full(SIDES, z1)]),
                          [[0.0, 0.0, z0], [0.0, 0.0, z1]]])
    bottom, top = 2 * SIDES, 2 * SIDES + 1
    faces = []
    for i in range(SIDES):
        j = (i + 1) % SIDES
        faces += [[i, j, SIDES + j], [i, SIDES + j, SIDES + i], [bottom, j, i], [top, SIDES + i, SIDES + j]]
    return vertices, np.array(faces)


def box(size: tuple[float, float, float], centre: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    half = np.asarray(size) / 2.0
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
             (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    return signs * half + np.asarray(centre), np.array(faces)


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Binary STL, float32, a zero header: the same mesh, the same bytes."""
    corners = vertices[faces].astype(np.float32)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    records = b"".join(struct.pack("<12fH", *n, *c.reshape(-1), 0) for n, c in zip(normals.astype(np.float32), corners, strict=True))
    path.write_bytes(bytes(80) + struct.pack("<I", len(faces)) + records)


def _f(value: float) -> str:
    return repr(round(float(value), 6))


def _inertial(mass: float, radius: float, length: float) -> str:
    ixx = mass * (3 * radius**2 + length**2) / 12.0
    izz = mass * radius**2 / 2.0
    return (f'<inertial><origin xyz="0 0 {_f(length / 2)}" rpy="0 0 0"/><mass value="{_f(mass)}"/>'
            f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(ixx)}" iyz="0" izz="{_f(izz)}"/></inertial>')


def write_random_arm(directory: Path, seed: int, n_joints: int | None = None, *, meshes: bool = True,
                     gripper: bool = False, package_uris: bool = False) -> GeneratedArm:
    rng = np.random.default_rng(seed)
    n = int(n_joints if n_joints is not None else rng.integers(4, 8))
    if not 4 <= n <= 7:
        raise ValueError(f"an arm of 4 to 7 joints, not {n}")
    directory.mkdir(parents=True, exist_ok=True)
    urdf_dir = directory / "urdf" if package_uris else directory
    mesh_folder = directory / PACKAGE / "meshes" if package_uris else directory / "meshes"
    urdf_dir.mkdir(parents=True, exist_ok=True)
    if meshes:
        mesh_folder.mkdir(parents=True, exist_ok=True)

    def mesh_ref(name: str) -> str:
        return f"package://{PACKAGE}/meshes/{name}" if package_uris else f"meshes/{name}"

    def collision(name: str, shape: tuple[np.ndarray, np.ndarray]) -> str:
        if not meshes:
            return ""
        write_stl(mesh_folder / name, *shape)
        return f'<collision><origin xyz="0 0 0" rpy="0 0 0"/><geometry><mesh filename="{mesh_ref(name)}"/></geometry></collision>'

    axes = ["0 0 1", "0 1 0", "0 1 0", "0 0 1", "0 1 0", "0 0 1", "0 1 0"]
    lengths = rng.uniform(0.08, 0.3, size=n)
    radii = np.linspace(0.05, 0.03, n)
    parts = [f'<robot name="generated_arm_{seed}">',
             f'<link name="base_link">{_inertial(2.0, 0.06, 0.08)}{collision("base_link.stl", prism(0.06, 0.0, 0.08))}</link>']
    parent, offset = "base_link", 0.08
    joint_names = []
    for i in range(n):
        name, link = f"joint{i + 1}", f"link{i + 1}"
        tilt = rng.uniform(-0.1, 0.1, size=2) if i > 0 else np.zeros(2)
        limit = rng.uniform(1.5, 2.9)
        parts.append(
            f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{link}"/>'
            f'<origin xyz="0 0 {_f(offset)}" rpy="{_f(tilt[0])} {_f(tilt[1])} 0"/><axis xyz="{axes[i]}"/>'
            f'<limit lower="{_f(-limit)}" upper="{_f(limit)}" velocity="{_f(rng.uniform(1.0, 3.0))}" '
            f'effort="{_f(rng.uniform(10.0, 150.0))}"/></joint>')
        parts.append(f'<link name="{link}">{_inertial(float(rng.uniform(0.5, 3.0)), radii[i], lengths[i])}'
                     f'{collision(f"{link}.stl", prism(radii[i], 0.0, lengths[i]))}</link>')
        joint_names.append(name)
        parent, offset = link, lengths[i]
    tool = rng.uniform(0.05, 0.1)
    gripper_joints: tuple[str, ...] = ()
    if gripper:
        parts.append(f'<joint name="hand_joint" type="fixed"><parent link="{parent}"/><child link="hand"/>'
                     f'<origin xyz="0 0 {_f(offset)}" rpy="0 0 0"/></joint>')
        parts.append(f'<link name="hand">{_inertial(0.4, 0.03, 0.04)}'
                     f'{collision("hand.stl", box((0.04, 0.12, 0.04), (0.0, 0.0, 0.02)))}</link>')
        for k, (side, mimic) in enumerate((("1", ""), ("-1", '<mimic joint="finger_joint1"/>'))):
            # closed, the two fingers' inner faces meet in the plane y = 0 of the hand
            inner = 0.0075 if side == "1" else -0.0075
            parts.append(f'<joint name="finger_joint{k + 1}" type="prismatic"><parent link="hand"/>'
                         f'<child link="finger{k + 1}"/><origin xyz="0 0 0.04" rpy="0 0 0"/><axis xyz="0 {side} 0"/>'
                         f'<limit lower="0" upper="0.04" velocity="0.1" effort="20"/>{mimic}</joint>')
            parts.append(f'<link name="finger{k + 1}">{_inertial(0.05, 0.01, 0.05)}'
                         f'{collision(f"finger{k + 1}.stl", box((0.02, 0.015, 0.05), (0.0, inner, 0.025)))}</link>')
        gripper_joints = ("finger_joint1",)
        parent, offset = "hand", 0.04 + tool
    else:
        offset += tool
    parts.append(f'<joint name="tool0_joint" type="fixed"><parent link="{parent}"/><child link="tool0"/>'
                 f'<origin xyz="0 0 {_f(offset)}" rpy="0 0 0"/></joint><link name="tool0"/>')
    parts.append("</robot>")
    urdf = urdf_dir / "arm.urdf"
    urdf.write_text("\n".join(parts) + "\n", encoding="utf-8")
    return GeneratedArm(urdf, directory, tuple(joint_names), "base_link", "tool0",
                        gripper_joints)


def write_mjcf_twin(arm: GeneratedArm, directory: Path) -> Path:
    """The same arm as MJCF, as MuJoCo converts the URDF (meshes copied beside it). Body placements
    are the URDF's at full precision, so the twin's kinematics equal the URDF's to ~1e-15 m. The arm's
    meshes must be relative (MuJoCo does not resolve package:// URIs)."""
    import shutil

    import mujoco

    spec = mujoco.MjSpec.from_file(str(arm.urdf))
    spec.compiler.fusestatic = False  # every link stays a body, tool0 included
    spec.compile()
    directory.mkdir(parents=True, exist_ok=True)
    meshes = directory / "meshes"
    meshes.mkdir(exist_ok=True)
    source = arm.urdf.parent / "meshes"
    for mesh in sorted(source.glob("*.stl")) if source.is_dir() else ():
        shutil.copyfile(mesh, meshes / mesh.name)
    path = directory / "arm.xml"
    path.write_text(_exact_placements(spec.to_xml(), arm.urdf), encoding="utf-8")
    return path


def _exact_placements(mjcf: str, urdf: Path) -> str:
    """The MJCF with each body's placement written at full precision from the URDF's joint origins
    (MuJoCo writes 6 significant digits, so its rpy → quaternion would move the TCP by ~1e-6 m)."""
    import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

    origins = {}
    for joint in ET.parse(urdf).getroot().iter("joint"):
        child, origin = joint.find("child"), joint.find("origin")
        if child is not None and origin is not None:
            rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()]
            xyzw = pin.Quaternion(pin.rpy.rpyToMatrix(*rpy)).coeffs()
            origins[child.get("link")] = (origin.get("xyz", "0 0 0"),
                                          " ".join(repr(float(v)) for v in (xyzw[3], xyzw[0], xyzw[1], xyzw[2])))
    root = ET.fromstring(mjcf)
    for body in root.iter("body"):
        if body.get("name") in origins:
            body.set("pos", origins[body.get("name")][0])
            body.set("quat", origins[body.get("name")][1])
    return ET.tostring(root, encoding="unicode")
