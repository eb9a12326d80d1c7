"""Loading an arm's description, URDF or MJCF, with its collision meshes found where the user keeps them.

Both formats go through Pinocchio (the kinematics ArmWarden computes with); MuJoCo loads the same
file for simulation. Mesh references are resolved before Pinocchio reads them, so a missing file is
named with its link and every place that was tried: a URDF's `package://pkg/path` is looked for
as `DIR/pkg/path` and `DIR/path` in each search directory (the description's folder first, then
the user's `--mesh-path`s), a relative path beside the description and then in each search
directory. xacro is the user's step (`xacro arm.urdf.xacro > arm.urdf`): a xacro file is refused
saying so. `description_chain.py` finds the arm in the loaded model.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError

#: the largest description read [bytes]; a description is kilobytes, never this
MAX_DESCRIPTION_BYTES = 16 * 1024 * 1024
XACRO_NAMESPACE = "{http://www.ros.org/wiki/xacro}"


@dataclass(frozen=True)
class Description:
    """A loaded description: the full model (every joint, gripper ones too) and, when asked for,
    its collision geometry with every mesh read."""

    path: Path
    kind: Literal["urdf", "mjcf"]
    model: pin.Model
    collision: pin.GeometryModel | None
    mesh_paths: tuple[Path, ...]
    #: joints that copy another joint (URDF `<mimic>`): never driven on their own
    mimic_joints: tuple[str, ...] = ()


def _read_root(path: Path) -> ET.Element:
    try:
        if path.stat().st_size > MAX_DESCRIPTION_BYTES:
            raise RobotModelError(f"robot description {path} is larger than {MAX_DESCRIPTION_BYTES} bytes")
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RobotModelError(f"cannot read robot description {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise RobotModelError(f"robot description {path} is not UTF-8 text: {exc}") from exc
    expanded = path.stem if path.stem.endswith(".urdf") else f"{path.stem}.urdf"
    if expanded == path.name:  # never tell anyone to overwrite the file being read
        expanded = f"{path.stem}.expanded.urdf"
    xacro = RobotModelError(f"{path} is a xacro file: expand it first (`xacro {path.name} > {expanded}`) and "
                            "give the URDF")
    if path.name.endswith(".xacro"):
        raise xacro
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        if "<xacro:" in text:  # xacro elements without the namespace declared
            raise xacro from exc
        raise RobotModelError(f"robot description {path} is not well-formed XML: {exc}") from exc
    # expanded URDFs often keep the xmlns:xacro declaration: what counts is a xacro element or a
    # ${...}/$(...) substitution left in
    for element in root.iter():
        if element.tag.startswith(XACRO_NAMESPACE) or any("${" in v or "$(" in v for v in element.attrib.values()):
            raise xacro
    return root


def _candidates(filename: str, description: Path, search: Sequence[Path]) -> list[Path]:
    """Where a mesh reference may be, in the order tried."""
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://"):].partition("/")
        return [place for directory in search for place in (directory / package / rest, directory / rest)]
    if filename.startswith("file://"):
        return [Path(filename[len("file://"):])]
    relative = Path(filename)
    if relative.is_absolute():
        return [relative]
    return [description.parent / relative, *(directory / relative for directory in search)]


def _resolved_urdf(root: ET.Element, path: Path, search: Sequence[Path]) -> str:
    """The URDF text with every collision mesh reference replaced by the file found for it."""
    missing = []
    for link in root.iter("link"):
        for mesh in link.findall("collision/geometry/mesh"):
            filename = mesh.get("filename", "")
            tried = _candidates(filename, path, search)
            found = next((place for place in tried if place.is_file()), None)
            if found is None:
                missing.append(f"link {link.get('name')!r}: {filename} (tried {', '.join(str(p) for p in tried)})")
            else:
                mesh.set("filename", str(found.resolve()))
    if missing:
        raise RobotModelError(f"{len(missing)} collision mesh(es) of {path} not found; give the folder that holds them "
                              "with --mesh-path (package://NAME/... is looked for as DIR/NAME/... and DIR/...): "
                              + "; ".join(missing))
    return ET.tostring(root, encoding="unicode")


def _mimic_joints(root: ET.Element) -> tuple[str, ...]:
    """Joints that follow another: URDF `<mimic>`, MJCF `<equality><joint joint1=...>` (joint1 follows joint2)."""
    if root.tag == "mujoco":
        pairs = (joint for equality in root.iter("equality") for joint in equality.findall("joint"))
        return tuple(dict.fromkeys(str(joint.get("joint1")) for joint in pairs if joint.get("joint1")))
    return tuple(str(joint.get("name")) for joint in root.iter("joint") if joint.find("mimic") is not None)


def _check_mjcf_meshes(root: ET.Element, path: Path) -> None:
    """Name every MJCF mesh file that is missing (Pinocchio would stop at the first, naming only the file).
    MJCF meshes are found through `<compiler meshdir>` (or `assetdir`), relative to the file."""
    compiler = root.find("compiler")
    meshdir = "" if compiler is None else compiler.get("meshdir", compiler.get("assetdir", ""))
    users: dict[str, list[str]] = {}
    for body in root.iter("body"):
        for geom in body.findall("geom"):
            if geom.get("mesh"):
                users.setdefault(str(geom.get("mesh")), []).append(str(body.get("name")))
    missing = []
    for mesh in root.iter("mesh"):
        filename = mesh.get("file")
        if not filename:
            continue
        place = Path(filename) if Path(filename).is_absolute() else path.parent / meshdir / filename
        if not place.is_file():
            name = mesh.get("name") or Path(filename).stem
            bodies = ", ".join(repr(b) for b in users.get(name, [])) or "no body"
            missing.append(f"mesh {name!r} of {bodies}: {filename} (tried {place})")
    if missing:
        raise RobotModelError(f"{len(missing)} mesh file(s) of {path} not found; an MJCF file finds its meshes "
                              "through <compiler meshdir=...> relative to itself (--mesh-path applies to URDFs): "
                              + "; ".join(missing))


#: joints ArmWarden cannot drive or bound: a free-floating or planar base, a ball joint
UNSUPPORTED_JOINTS = {"JointModelFreeFlyer": "floating", "JointModelPlanar": "planar", "JointModelSpherical": "spherical",
                      "JointModelSphericalZYX": "spherical"}


def _refuse_free_joints(model: pin.Model, path: Path) -> None:
    """A fixed-base arm of revolute joints (and prismatic fingers) only: the checks bound every
    joint by one position interval, which a floating, planar or ball joint does not have."""
    bad = [f"{model.names[j]} ({UNSUPPORTED_JOINTS[model.joints[j].shortname()]})" for j in range(1, model.njoints)
           if model.joints[j].shortname() in UNSUPPORTED_JOINTS]
    if bad:
        raise RobotModelError(f"robot description {path} has joints ArmWarden does not support: {', '.join(bad)}; "
                              "an arm is fixed to the world and moves by revolute joints (fingers may be prismatic)")


def load_description(path: Path, mesh_paths: Sequence[Path] = (), *, with_collision: bool = True) -> Description:
    """The description at `path` (URDF or MJCF, told apart by its root element), its collision
    geometry read when `with_collision`. `RobotModelError` says what is wrong and what to do."""
    path = Path(path)
    root = _read_root(path)
    search = (path.parent, *(Path(p) for p in mesh_paths))
    if root.tag == "robot":
        kind: Literal["urdf", "mjcf"] = "urdf"
    elif root.tag == "mujoco":
        kind = "mjcf"
    else:
        raise RobotModelError(f"{path} is neither a URDF (<robot>) nor an MJCF (<mujoco>) file: its root is <{root.tag}>")
    try:
        model = pin.buildModelFromUrdf(str(path)) if kind == "urdf" else pin.buildModelFromMJCF(str(path))
    except Exception as exc:  # the parsers raise ValueError/RuntimeError with their own text
        raise RobotModelError(f"cannot load robot description {path}: {exc}") from exc
    _refuse_free_joints(model, path)
    collision = None
    if with_collision:
        try:
            if kind == "urdf":
                collision = pin.buildGeomFromUrdfString(model, _resolved_urdf(root, path, search), pin.GeometryType.COLLISION)
            else:
                _check_mjcf_meshes(root, path)
                collision = pin.buildGeomFromMJCF(model, str(path), pin.GeometryType.COLLISION)
        except RobotModelError:
            raise
        except Exception as exc:
            raise RobotModelError(f"cannot read the collision geometry of {path}: {exc}") from exc
    return Description(path, kind, model, collision, tuple(Path(p) for p in mesh_paths),
                       _mimic_joints(root))


__all__ = ["MAX_DESCRIPTION_BYTES", "UNSUPPORTED_JOINTS", "Description", "load_description"]
