"""Fit capsules to the FR3's and the Franka Hand's collision geometry and analyse self-collision pairs.

    .venv/bin/python scripts/fit_geometry.py --source PATH [--commit REV] [--out FILE] [--vertices FILE]
    .venv/bin/python scripts/fit_geometry.py --source PATH --check      # exit 1 if FILE would change

PATH is franka_description (https://github.com/frankaemika/franka_description, Apache-2.0): a
checkout, or a bare git directory (then files are read at REV with `git show`). Nothing from it
is written into the project except the fitted capsules and the pair analysis (FILE, by default
src/armwarden/robots/fr3/fitted.yaml); `--vertices` also writes the unique
collision-mesh vertices per link (link frame, float32 .npz; `--only-vertices`: that alone) that
tests/robot/test_fitted_geometry.py checks containment against — derived from Franka's meshes, so
it is not committed (see tests/robot/data/README.md). `--evaluate N` counts self-collisions on N
random configurations: the meshes (coal) against the fitted capsules and today's.

Needs the `fit` extra (trimesh) to read the meshes. Same source, same bytes.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import io
import math
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

from armwarden.robot.fitted_file import FittedGeometry, LinkFit, load_fitted, render_fitted  # noqa: E402 - the src path above first
from armwarden.robot.fitting import FitOptions, fit_link, rotate_fit  # noqa: E402
from armwarden.robot.fitting_mesh import LinkMesh, box_mesh, load_mesh, merge_meshes, transform_mesh  # noqa: E402
from armwarden.robot.model import resolve_description  # noqa: E402
from armwarden.robot.pairs import PairOptions, analyse_pairs, place_bodies  # noqa: E402

REPOSITORY = "https://github.com/frankaemika/franka_description"
LICENCE = "Apache-2.0 (LICENSE and NOTICE of the repository: Copyright 2023 Franka Robotics GmbH)"
ARM_MESHES = {f"fr3_link{i}": f"meshes/robot_arms/fr3/collision/link{i}.stl" for i in range(8)}
HAND_MESH = ("fr3_hand", "meshes/robot_ee/franka_hand_white/collision/hand.stl")
HAND_XACRO = "end_effectors/common/franka_hand.xacro"
KINEMATICS = "robots/fr3/kinematics.yaml"
DEFAULT_OUT = ROOT / "src" / "armwarden" / "robots" / "fr3" / "fitted.yaml"


@dataclass(frozen=True)
class Source:
    """franka_description, as a work tree or a (bare) git directory read at one commit."""

    path: Path
    commit: str | None  # None: a plain directory

    @classmethod
    def open(cls, path: Path, revision: str) -> Source:
        if ((path / "objects").is_dir() and (path / "HEAD").is_file()) or (path / ".git").exists():
            git_dir = path if (path / "objects").is_dir() else path / ".git"
            commit = subprocess.run(["git", "--git-dir", str(git_dir), "rev-parse", f"{revision}^{{commit}}"],
                                    check=True, capture_output=True, text=True).stdout.strip()
            return cls(git_dir, commit)
        return cls(path, None)

    def read(self, relative: str) -> bytes:
        if self.commit is None:
            return (self.path / relative).read_bytes()
        return subprocess.run(["git", "--git-dir", str(self.path), "show", f"{self.commit}:{relative}"],
                              check=True, capture_output=True).stdout


def _expression(text: str) -> float:
    """A xacro number: a literal or `${…}` of numbers, `pi`, + − * / and parentheses only
    (evaluated from its syntax tree here, never by `eval`)."""
    text = text.strip()
    if text.startswith("${") and text.endswith("}"):
        text = text[2:-1]
    operators = {ast.Add: float.__add__, ast.Sub: float.__sub__, ast.Mult: float.__mul__, ast.Div: float.__truediv__}

    def value(node: ast.AST) -> float:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
            return float(node.value)
        if isinstance(node, ast.Name) and node.id == "pi":
            return math.pi
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            return -value(node.operand) if isinstance(node.op, ast.USub) else value(node.operand)
        if isinstance(node, ast.BinOp) and type(node.op) in operators:
            return operators[type(node.op)](value(node.left), value(node.right))
        raise ValueError(f"not a plain numeric xacro expression: {text!r}")

    return value(ast.parse(text, mode="eval").body)


def _split_expressions(text: str) -> list[float]:
    return [_expression(part) for part in re.findall(r"\$\{[^}]*\}|[^\s]+", text)]


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF rpy: R = Rz(yaw) · Ry(pitch) · Rx(roll)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def finger_meshes(source: Source) -> dict[str, LinkMesh]:
    """The fingers' collision boxes from the hand xacro, each in *Franka's* finger frame."""
    root = ET.fromstring(source.read(HAND_XACRO))
    meshes = {}
    for side in ("leftfinger", "rightfinger"):
        link = next(e for e in root.iter("link") if e.get("name", "").endswith(side))
        boxes = []
        for collision in link.iter("collision"):
            box = collision.find("geometry/box")
            origin = collision.find("origin")
            if box is None or origin is None:
                raise SystemExit(f"{HAND_XACRO}: a {side} collision that is not an <origin>ed <box>")
            size = _split_expressions(box.get("size", ""))
            xyz = _split_expressions(origin.get("xyz", "0 0 0"))
            rpy = _split_expressions(origin.get("rpy", "0 0 0"))
            boxes.append(box_mesh(f"fr3_{side}", size, xyz, rpy_matrix(*rpy), f"{HAND_XACRO} ({side} box)"))
        meshes[f"fr3_{side}"] = merge_meshes(f"fr3_{side}", boxes, f"{HAND_XACRO}: {side} collision boxes ({len(boxes)})")
    return meshes


#: Franka's frame of each link in ArmWarden's (p_ours = R p_franka). Franka's right finger joint
#: turns its frame by pi about z (`rpy="0 0 ${pi}"`, axis +y); fr3.urdf keeps the frame and moves
#: the finger along -y instead. Fits are made in Franka's frame (both fingers' boxes are the same
#: there, so both fits are) and turned: an exact sign flip of x and y.
FRANKA_TO_OURS = {"fr3_rightfinger": rpy_matrix(0.0, 0.0, math.pi).round(12)}


def check_kinematics(source: Source, urdf: Path) -> None:
    """Fail unless Franka's joint origins equal the bundled URDF's: the meshes' link frames are ours."""
    kinematics = yaml.safe_load(source.read(KINEMATICS))
    joints = {j.get("name"): j for j in ET.parse(urdf).getroot().iter("joint")}
    for number in range(1, 9):
        ours = joints[f"fr3_joint{number}"].find("origin")
        theirs = kinematics[f"joint{number}"]["kinematic"]
        expected = [theirs[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]
        assert ours is not None
        got = [float(v) for v in ours.get("xyz", "0 0 0").split()] + [float(v) for v in ours.get("rpy", "0 0 0").split()]
        if not np.allclose(got, expected, atol=1e-9):
            raise SystemExit(f"fr3_joint{number}: bundled URDF origin {got} differs from {KINEMATICS} {expected}")


def load_links(source: Source) -> dict[str, LinkMesh]:
    meshes = {link: load_mesh(link, source.read(path), "stl", path) for link, path in ARM_MESHES.items()}
    meshes[HAND_MESH[0]] = load_mesh(HAND_MESH[0], source.read(HAND_MESH[1]), "stl", HAND_MESH[1])
    meshes.update(finger_meshes(source))
    return meshes


def fitting_input(meshes: dict[str, LinkMesh]) -> dict[str, LinkMesh]:
    """What each link is fitted to: its own mesh, except that the right finger, the same part as
    the left in Franka's frames (checked to 1e-9 m), is fitted to the left finger's boxes, so
    that both fingers get the same capsules (the fit is not equivariant to the last bit)."""
    left, right = meshes["fr3_leftfinger"], meshes["fr3_rightfinger"]
    corners = [np.unique(np.round(mesh.vertices, 9), axis=0) for mesh in (left, right)]
    if corners[0].shape != corners[1].shape or not np.allclose(corners[0], corners[1], atol=2e-9):
        raise SystemExit("the right finger's collision boxes are not the left finger's: fit them apart")
    return {**meshes, "fr3_rightfinger": replace(left, link="fr3_rightfinger", source=right.source)}


def vertex_cloud(meshes: dict[str, LinkMesh]) -> dict[str, np.ndarray]:
    """Each link's unique vertices in ArmWarden's link frame (float32, sorted)."""
    cloud = {}
    for link, mesh in meshes.items():
        turned = transform_mesh(mesh, FRANKA_TO_OURS.get(link, np.eye(3)), (0.0, 0.0, 0.0))
        cloud[link] = np.unique(turned.unique_vertices().astype(np.float32), axis=0)
    return cloud


def cloud_digest(cloud: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(cloud, dtype="<f4").tobytes()).hexdigest()


def header(source: Source, options: FitOptions) -> list[str]:
    lines = [
        "Capsules fitted to the collision geometry of the Franka Research 3 and the Franka Hand, and the",
        "self-collision pair analysis on them. GENERATED by scripts/fit_geometry.py; do not edit by hand.",
        "",
        f"Source: {REPOSITORY}",
        f"  at commit {source.commit or '(a work tree)'}:",
        "  meshes/robot_arms/fr3/collision/link0.stl ... link7.stl,",
        f"  {HAND_MESH[1]},",
        f"  and the finger collision boxes of {HAND_XACRO}.",
        f"Licence of the source: {LICENCE}.",
        "The meshes carry no <origin> in the xacro (the mesh frame is the link frame); the joint origins",
        f"are checked equal to the bundled fr3.urdf's against {KINEMATICS}. The right finger is fitted in",
        "Franka's frame and turned by pi about z (Franka turns that finger's frame; fr3.urdf moves it along -y).",
        "",
        "Each body is a capsule in its link's frame [m]: segment p0-p1 swept by a ball of `radius`.",
        f"Every mesh triangle lies inside one capsule with at least margin_m = {options.margin_m} m to spare",
        f"(triangles halved to <= {options.max_edge_m} m; interior grid points every {options.interior_pitch_m} m also inside).",
        "worst_over_approximation_m: the largest distance from the fitted surface to the mesh, measured on",
        f"points <= {options.surface_spacing_m} m apart. tried_m: the same, on points twice as far apart, with 1, 2, ...",
        "capsules (for a mesh of several parts: each part's chosen capsules).",
        "vertices_sha256: SHA-256 of the link's unique vertices (float32 little-endian, sorted) the fit holds.",
        "pairs: every pair of bodies on different links is included (checked) or excluded with its proof over",
        "joint_limits (armwarden.robot.pairs): apart, overlapping, or adjacent (links one joint apart in contact).",
    ]
    return lines


def _joints_between(model: pin.Model, a: int, b: int) -> int:
    def chain(j: int) -> set[int]:
        out = {j}
        while j != 0:
            j = int(model.parents[j])
            out.add(j)
        return out

    return len(chain(a) ^ chain(b))


def evaluate(meshes: dict[str, LinkMesh], geometry: FittedGeometry, samples: int, seed: int) -> None:
    """Self-collision on random configurations within the limits: the meshes (coal, the ground
    truth) against the fitted capsules with the analysed pairs and against today's capsules.

    Printed, not written: the numbers for docs and reports. Link pairs joined by one joint (or
    none) are in contact by construction and not counted; the fingers' contact with each other
    (a closed gripper) is counted apart.
    """
    import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

    from armwarden.core.geometry import segment_segment_distance
    from armwarden.robot.model import RobotModel

    urdf = resolve_description("builtin:fr3")
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    frames = {link: model.getFrameId(link, pin.FrameType.BODY) for link in meshes}
    joint_of = {link: int(model.frames[f].parentJoint) for link, f in frames.items()}
    shapes = {}
    for link, mesh in meshes.items():
        turned = transform_mesh(mesh, FRANKA_TO_OURS.get(link, np.eye(3)), (0.0, 0.0, 0.0))
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(turned.triangles), len(turned.vertices))
        bvh.addVertices(np.ascontiguousarray(turned.vertices, dtype=float))
        bvh.addTriangles(np.ascontiguousarray(turned.triangles, dtype=np.int64))
        bvh.endModel()
        shapes[link] = bvh
    names = list(meshes)
    fingers = {"fr3_leftfinger", "fr3_rightfinger"}
    link_pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:] if _joints_between(model, joint_of[a], joint_of[b]) >= 2]
    placed = {b.name: b for b in place_bodies(model, geometry)}
    included = [(placed[a], placed[b]) for a, b in geometry.included_pairs]

    arm = [f"fr3_joint{i}" for i in range(1, 8)]
    today = RobotModel(urdf, arm, "fr3_link0", "fr3_hand_tcp")
    caps = today.capsules
    today_pairs = [(int(i), int(j)) for i, j in today.self_collision_pairs]  # the URDF path's neighbour rule

    rng = np.random.default_rng(seed)
    arm_idx = [model.joints[model.getJointId(n)].idx_q for n in arm]
    finger_idx = [model.joints[model.getJointId(n)].idx_q for n in ("fr3_finger_joint1", "fr3_finger_joint2")]
    lower, upper = model.lowerPositionLimit[arm_idx], model.upperPositionLimit[arm_idx]
    request, counts, gaps = coal.CollisionRequest(), {}, []
    wrist = {"mesh": 0, "fitted": 0, "today": 0, "configs": 0}
    fitted_hits = mesh_hits = today_hits = fitted_only = mesh_only = finger_contact = today_missed = 0
    for _ in range(samples):
        q = pin.neutral(model)
        q[arm_idx] = lower + rng.random(7) * (upper - lower)
        q[finger_idx] = rng.random() * 0.04
        pin.framesForwardKinematics(model, data, q)
        poses = {link: data.oMf[f] for link, f in frames.items()}
        mesh_pairs = set()
        for a, b in link_pairs:
            result = coal.CollisionResult()
            ta = coal.Transform3s(poses[a].rotation, poses[a].translation)
            tb = coal.Transform3s(poses[b].rotation, poses[b].translation)
            if coal.collide(shapes[a], ta, shapes[b], tb, request, result):
                mesh_pairs.add((a, b))
        fitted_pairs = set()
        for x, y in included:
            mx, my = data.oMi[x.joint], data.oMi[y.joint]
            if segment_segment_distance(mx.act(x.p0), mx.act(x.p1), my.act(y.p0), my.act(y.p1)) < x.radius_m + y.radius_m:
                fitted_pairs.add(tuple(sorted((x.link, y.link))))
        frames_today = today.joint_frames(q[arm_idx][None])
        p0, p1 = today.body_points(frames_today)
        today_links = set()
        for i, j in today_pairs:
            if segment_segment_distance(p0[0, i], p1[0, i], p0[0, j], p1[0, j]) < caps[i].radius_m + caps[j].radius_m:
                today_links.add(tuple(sorted((caps[i].link, caps[j].link))))
        finger_contact += ("fr3_leftfinger", "fr3_rightfinger") in mesh_pairs
        mesh_any = any(set(p) != fingers for p in mesh_pairs)
        fitted_any = any(set(p) != fingers for p in fitted_pairs)
        mesh_hits += mesh_any
        fitted_hits += fitted_any
        today_hits += bool(today_links)
        fitted_only += fitted_any and not mesh_any
        mesh_only += mesh_any and not fitted_any
        today_missed += mesh_any and not today_links
        for pair in fitted_pairs | {tuple(sorted(p)) for p in mesh_pairs} | today_links:
            counts.setdefault(pair, [0, 0, 0])
        for pair in {tuple(sorted(p)) for p in mesh_pairs}:
            counts[pair][0] += 1
        for pair in fitted_pairs:
            counts[pair][1] += 1
            if pair not in {tuple(sorted(p)) for p in mesh_pairs} and set(pair) != fingers:
                a, b = pair
                ta = coal.Transform3s(poses[a].rotation, poses[a].translation)
                tb = coal.Transform3s(poses[b].rotation, poses[b].translation)
                gaps.append(coal.distance(shapes[a], ta, shapes[b], tb, coal.DistanceRequest(), coal.DistanceResult()))
        for pair in today_links:
            counts[pair][2] += 1
        if q[arm_idx[5]] >= 2.7:
            wrist["configs"] += 1
            wrist["mesh"] += ("fr3_link5", "fr3_link7") in mesh_pairs
            wrist["fitted"] += ("fr3_link5", "fr3_link7") in fitted_pairs
            wrist["today"] += ("fr3_link5", "fr3_link7") in today_links
    print(f"{samples} configurations (seed {seed}), arm uniform within the limits, gripper width uniform 0-0.08 m")
    print(f"self-colliding (fingers against each other not counted): meshes {mesh_hits}, fitted {fitted_hits}, "
          f"today's capsules {today_hits}")
    print(f"fitted says colliding where the meshes do not: {fitted_only}; the meshes collide where the fitted "
          f"capsules do not: {mesh_only} (today's capsules: {today_missed}); fingers touching each other (meshes): "
          f"{finger_contact}")
    print(f"link5 vs link7 with joint 6 >= 2.7 rad ({wrist['configs']} configurations): meshes {wrist['mesh']}, "
          f"fitted {wrist['fitted']}, today {wrist['today']}")
    if gaps:
        print(f"where the fitted capsules of a link pair touch and its meshes do not, the meshes are "
              f"{np.median(gaps) * 1e3:.1f} mm apart (median), {np.max(gaps) * 1e3:.1f} mm at most ({len(gaps)} link pairs)")
    print("per link pair (meshes / fitted / today):")
    for pair, (m, f, t) in sorted(counts.items()):
        print(f"  {pair[0]} - {pair[1]}: {m} / {f} / {t}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--source", type=Path, required=True, help="franka_description: a checkout or a git directory")
    parser.add_argument("--commit", default="HEAD", help="revision to read from a git directory")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--vertices", type=Path, default=None, help="also write the per-link vertex cloud (.npz)")
    parser.add_argument("--only-vertices", action="store_true", help="write the --vertices cloud, fit nothing")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if --out would change")
    parser.add_argument("--margin-m", type=float, default=FitOptions.margin_m)
    parser.add_argument("--max-bodies", type=int, default=FitOptions.max_bodies)
    parser.add_argument("--links", nargs="*", default=None,
                        help="fit only these links (the others are kept from FILE when it exists)")
    parser.add_argument("--pairs-only", action="store_true", help="keep FILE's capsules, redo the pair analysis")
    parser.add_argument("--evaluate", type=int, default=0, metavar="N",
                        help="fit nothing: count self-collisions of N random configurations (meshes, fitted FILE, today)")
    args = parser.parse_args(argv)

    source = Source.open(args.source, args.commit)
    urdf = resolve_description("builtin:fr3")
    check_kinematics(source, urdf)
    meshes = load_links(source)
    if args.only_vertices:
        if args.vertices is None:
            parser.error("--only-vertices needs --vertices FILE")
        write_cloud(args.vertices, vertex_cloud(meshes))
        return 0
    if args.evaluate:
        evaluate(meshes, load_fitted(args.out), args.evaluate, seed=2025)
        return 0
    options = FitOptions(margin_m=args.margin_m, max_bodies=args.max_bodies)
    if args.pairs_only:
        geometry = load_fitted(args.out)
        options = replace(options, margin_m=geometry.margin_m)
    else:
        geometry = fit_links(source, meshes, options, args.links)
        if args.links and args.out.exists():  # the other links as they were
            kept = load_fitted(args.out)
            geometry = replace(geometry, links={name: geometry.links.get(name, fit) for name, fit in kept.links.items()})
        if not args.check:  # the capsules are kept even if the pair analysis is stopped
            args.out.write_text(render_fitted(geometry, header(source, options)), encoding="utf-8")
    model = pin.buildModelFromUrdf(str(urdf))
    analysis = analyse_pairs(model, place_bodies(model, geometry), PairOptions())
    decided: dict[str, int] = {}
    for verdict in analysis.verdicts:
        decided[verdict.decision] = decided.get(verdict.decision, 0) + 1
    print(f"body pairs: {decided}", file=sys.stderr)
    geometry = replace(geometry, joint_limits=analysis.joint_limits, pair_clearance_m=analysis.clearance_m,
                       included_pairs=analysis.included, excluded_pairs=analysis.excluded)
    text = render_fitted(geometry, header(source, options))
    if args.check:
        current = args.out.read_text(encoding="utf-8") if args.out.exists() else ""
        if current != text:
            print(f"{args.out} would change", file=sys.stderr)
            return 1
        print(f"{args.out} is up to date", file=sys.stderr)
        return 0
    args.out.write_text(text, encoding="utf-8")
    if args.vertices is not None:
        write_cloud(args.vertices, vertex_cloud(meshes))
    return 0


def fit_links(source: Source, meshes: dict[str, LinkMesh], options: FitOptions, only: list[str] | None) -> FittedGeometry:
    """Every link's capsules (the right finger's turned into fr3.urdf's frame), with the digest of
    the vertex cloud each holds."""
    cloud = vertex_cloud(meshes)
    inputs = fitting_input(meshes)
    fits: dict[str, LinkFit] = {}
    for name, mesh in inputs.items():
        if only and name not in only:
            continue
        fit = fit_link(mesh, options)
        if name in FRANKA_TO_OURS:
            fit = rotate_fit(fit, FRANKA_TO_OURS[name], name, options.decimals)
        fits[name] = replace(fit, vertices_sha256=cloud_digest(cloud[name]))
        print(f"{name}: {len(fits[name].bodies)} capsules, worst over-approximation "
              f"{fits[name].worst_over_approximation_m * 1e3:.1f} mm (tried {fits[name].tried_m})", file=sys.stderr)
    return FittedGeometry(
        robot="fr3",
        source={"repository": REPOSITORY, "commit": source.commit or "work tree", "licence": "Apache-2.0"},
        margin_m=options.margin_m,
        links=fits,
    )


def write_cloud(path: Path, cloud: dict[str, np.ndarray]) -> None:
    buffer = io.BytesIO()
    np.savez(buffer, **cloud)  # pyright: ignore[reportArgumentType] - link names, never numpy's keywords
    path.write_bytes(buffer.getvalue())


if __name__ == "__main__":
    raise SystemExit(main())
