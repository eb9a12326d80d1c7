#!/usr/bin/env python3
"""Dense collision check of executed joint paths against the table and keep-out zones.

Verification tooling (tests and benchmarks), never runtime: an oracle beside the envelope, sharing
none of its code, that says whether a joint path the backend was sent stays clear of the table
(the plane z = 0 of the base frame) and of the policy's keep-out boxes. Two geometries:

- the **fitted capsules** of `src/armwarden/robots/fr3/fitted.yaml`, exactly as the
  file states them, *without* padding. They contain Franka's collision meshes with a margin (a
  test per link holds that), so a path clear of them is clear of the meshes. Needs nothing but
  the repository: the CI level.
- **Franka's collision meshes** themselves (link frames, from a local cache `write_mesh_cache`
  makes out of franka_description; fetched material, never committed): the local level.

How a path is checked:

- Between two waypoints the path is the straight line in joint space (what every backend
  executes, `armwarden.core.trajectory`). Each such segment is cut so that between two checked
  configurations no point of any body moves more than `max_step_m` (1 mm by default): joint i
  turning by Δ moves a point at most `reach_i`·|Δ|, with `reach_i` the bound of
  `RobotModel._compute_reach` (the joint-to-joint offsets along the chain plus the body's
  farthest point from its own joint), computed here over the points of the geometry checked
  (capsule end points plus their radius, or mesh vertices), so it bounds every surface point.
- Table: a moving body is clear when its lowest point is above z = 0: for a capsule
  min(z0, z1) − r, for a mesh its lowest vertex (exact: a triangle's lowest point is a corner).
  `fr3_link0` is bolted to the table and never moves; it is checked against the zones only.
- Zones: a broad phase on each body's axis-aligned bounds in numpy, then coal's exact `collide`
  and `distance` for every body whose bounds come within `BROAD_MARGIN_M` of a zone.

`python scripts/_bench/dense_check.py --source PATH --write-meshes FILE` writes the mesh cache
from a franka_description checkout or bare git directory (needs trimesh, the `fit` extra); the
default FILE is `tests/planning/data/fr3_collision_meshes.npz`, which git ignores.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT / "src") not in sys.path:  # after PYTHONPATH: a copy of the sources named there wins
    sys.path.append(str(ROOT / "src"))

from armwarden.robot.fitted_file import load_fitted  # noqa: E402 - the src path above first
from armwarden.robot.model import resolve_description  # noqa: E402

FITTED = ROOT / "src" / "armwarden" / "robots" / "fr3" / "fitted.yaml"
#: the local mesh cache (derived from Franka's meshes: git ignores it, see tests/planning/data/README.md)
MESH_CACHE = ROOT / "tests" / "planning" / "data" / "fr3_collision_meshes.npz"
#: environment variable naming another mesh cache
MESH_CACHE_ENV = "ARMWARDEN_FR3_MESHES"
ARM_JOINTS = tuple(f"fr3_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("fr3_finger_joint1", "fr3_finger_joint2")
#: the link bolted to the table: it never moves, so it is not checked against the table
BASE_LINK = "fr3_link0"
#: bodies whose bounds come this close to a zone get coal's exact distance [m]
BROAD_MARGIN_M = 0.05
MAX_STEP_M = 0.001
CHUNK = 1024


@dataclass(frozen=True)
class Zone:
    """A keep-out box in the base frame [m]."""

    name: str
    lo: np.ndarray
    hi: np.ndarray

    def shape(self) -> tuple[coal.Box, coal.Transform3s]:
        return coal.Box(self.hi - self.lo), coal.Transform3s(np.eye(3), (self.lo + self.hi) / 2.0)


def policy_zones(policy: object) -> tuple[Zone, ...]:
    """The keep-out zones of a loaded policy."""
    return tuple(Zone(z.name, np.array(z.min, dtype=float), np.array(z.max, dtype=float))
                 for z in policy.workspace.keep_out)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Body:
    """One collision shape, placed on the joint that moves it (Pinocchio joint frame)."""

    name: str
    link: str
    joint: int  # index into the arm's joint slots (0-based: joint 1 is 0); -1 fixed to the base
    points: np.ndarray  # (k, 3) joint-frame points: capsule ends, or mesh vertices
    radius_m: float  # swept around `points` (capsules); 0 for a mesh
    shape: coal.CollisionGeometry
    local: coal.Transform3s  # the shape in the joint frame


@dataclass(frozen=True)
class Geometry:
    """A set of bodies and what it is ("fitted capsules", "meshes")."""

    kind: str
    bodies: tuple[Body, ...]


class ArmKinematics:
    """The bundled FR3 description reduced to its seven arm joints, fingers locked at one width.

    Only joint placements are computed per configuration (Pinocchio's forward kinematics); bodies
    are stored in their joint's frame."""

    def __init__(self, gripper_width_m: float, description: str = "builtin:fr3") -> None:
        full = pin.buildModelFromUrdf(str(resolve_description(description)))
        reference = pin.neutral(full)
        lock = []
        for jid in range(1, full.njoints):
            name = full.names[jid]
            if name in ARM_JOINTS:
                continue
            lock.append(jid)
            if name in FINGER_JOINTS:
                reference[full.joints[jid].idx_q] = gripper_width_m / 2.0
        self.full = full
        self.model = pin.buildReducedModel(full, lock, reference)
        self.data = self.model.createData()
        if list(self.model.names)[1:] != list(ARM_JOINTS):
            raise ValueError(f"unexpected joints {list(self.model.names)[1:]}")
        self.gripper_width_m = gripper_width_m
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        self._refs = [self.data.oMi[j] for j in range(1, self.model.njoints)]
        self._joint_tables = [(self.model.jointPlacements[j].homogeneous.copy(), _revolute_axis(self.model, j))
                              for j in range(1, self.model.njoints)]

    def joint_frames_pinocchio(self, qs: np.ndarray) -> np.ndarray:
        """`joint_frames` by Pinocchio's forward kinematics, one configuration at a time (the reference)."""
        out = np.empty((len(qs), len(self._refs), 4, 4))
        for n, q in enumerate(qs):
            pin.forwardKinematics(self.model, self.data, q)
            for k, ref in enumerate(self._refs):
                out[n, k] = ref.np
        return out

    def link_in_joint(self, link: str) -> tuple[int, pin.SE3]:
        """(joint slot, the link frame in that joint's frame); slot -1 for a link fixed to the base."""
        frame = self.model.frames[self.model.getFrameId(link, pin.FrameType.BODY)]
        return int(frame.parentJoint) - 1, frame.placement

    def joint_frames(self, qs: np.ndarray) -> np.ndarray:
        """(N, 7, 4, 4) placements of the seven arm joints in the base frame (= Pinocchio's world),
        vectorised over the batch: each joint's placement in its parent times its rotation about
        its axis, read from the Pinocchio model (a test holds it equal to Pinocchio's to 1e-12)."""
        qs = np.asarray(qs, dtype=float).reshape(-1, self.model.nq)
        n = len(qs)
        out = np.empty((n, len(self._refs), 4, 4))
        parent_of = [int(self.model.parents[j]) for j in range(1, self.model.njoints)]
        for k, (placement, axis) in enumerate(self._joint_tables):
            c, s = np.cos(qs[:, k]), np.sin(qs[:, k])
            cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
            # Rodrigues: R = I + sin θ [a]× + (1 − cos θ) [a]×²
            motion = np.zeros((n, 4, 4))
            motion[:, :3, :3] = np.eye(3) + s[:, None, None] * cross + (1.0 - c)[:, None, None] * (cross @ cross)
            motion[:, 3, 3] = 1.0
            local = placement @ motion  # (n, 4, 4)
            parent = parent_of[k]
            out[:, k] = local if parent == 0 else out[:, parent - 1] @ local
        return out

    def tcp_pose(self, q: np.ndarray, frame: str = "fr3_hand_tcp") -> pin.SE3:
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.model.getFrameId(frame)].copy()


def _revolute_axis(model: pin.Model, joint: int) -> np.ndarray:
    """The unit axis of a revolute joint in its own frame; any other kind of joint is refused."""
    name = model.joints[joint].shortname()
    axes = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}
    if name in axes:
        return np.array(axes[name])
    if name == "JointModelRevoluteUnaligned":
        return np.asarray(model.joints[joint].extract().axis, dtype=float)
    raise ValueError(f"joint {model.names[joint]!r} is a {name}: only revolute arm joints are supported")


def _capsule_shape(p0: np.ndarray, p1: np.ndarray, radius: float) -> tuple[coal.CollisionGeometry, coal.Transform3s]:
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    centre = (p0 + p1) / 2.0
    if length < 1e-12:
        return coal.Sphere(radius), coal.Transform3s(np.eye(3), centre)
    z = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    rotation = np.column_stack([x, np.cross(z, x), z])
    return coal.Capsule(radius, length / 2.0), coal.Transform3s(rotation, centre)


def fitted_capsules(arm: ArmKinematics, path: Path = FITTED) -> Geometry:
    """The fitted capsules as the file states them (no padding), on their joints."""
    bodies = []
    for link, fit in load_fitted(path).links.items():
        slot, placement = arm.link_in_joint(link)
        for body in fit.bodies:
            p0 = placement.act(np.array(body.p0_m, dtype=float))
            p1 = placement.act(np.array(body.p1_m, dtype=float))
            shape, local = _capsule_shape(p0, p1, body.radius_m)
            bodies.append(Body(body.name, link, slot, np.vstack([p0, p1]), body.radius_m, shape, local))
    return Geometry("fitted capsules", tuple(bodies))


@dataclass(frozen=True)
class Meshes:
    """Franka's collision meshes in ArmWarden's link frames [m], from the local cache."""

    vertices: dict[str, np.ndarray]
    triangles: dict[str, np.ndarray]
    commit: str


def mesh_cache_path() -> Path:
    return Path(os.environ.get(MESH_CACHE_ENV, MESH_CACHE))


def load_meshes(path: Path | None = None) -> Meshes | None:
    """The mesh cache, or None when there is none (the local level then cannot run)."""
    path = path or mesh_cache_path()
    if not path.is_file():
        return None
    with np.load(path) as data:
        links = sorted({key.split("/")[0] for key in data.files if "/" in key})
        return Meshes({link: data[f"{link}/vertices"] for link in links},
                      {link: data[f"{link}/triangles"] for link in links}, str(data["commit"]))


def mesh_bodies(arm: ArmKinematics, meshes: Meshes) -> Geometry:
    """One BVH per link mesh, its vertices in the joint frame."""
    bodies = []
    for link, vertices in meshes.vertices.items():
        slot, placement = arm.link_in_joint(link)
        points = vertices @ placement.rotation.T + placement.translation
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(meshes.triangles[link]), len(points))
        bvh.addVertices(np.ascontiguousarray(points, dtype=float))
        bvh.addTriangles(np.ascontiguousarray(meshes.triangles[link], dtype=np.int64))
        bvh.endModel()
        bodies.append(Body(link, link, slot, points, 0.0, bvh, coal.Transform3s()))
    return Geometry("meshes", tuple(bodies))


def reach_bound(arm: ArmKinematics, geometry: Geometry) -> np.ndarray:
    """Per arm joint, a bound [m/rad] on how far any point of any body moves per radian of that
    joint: `RobotModel._compute_reach`'s bound (offsets along the chain from the joint to the body's
    joint, plus the body's farthest point from its own joint), maximised over the bodies it moves."""
    model = arm.model
    bound = np.zeros(model.nq)
    for body in geometry.bodies:
        if body.joint < 0:
            continue
        far = float(np.max(np.linalg.norm(body.points, axis=1))) + body.radius_m
        joint, offset = body.joint + 1, 0.0
        while joint > 0:
            bound[model.joints[joint].idx_q] = max(bound[model.joints[joint].idx_q], offset + far)
            offset += float(np.linalg.norm(model.jointPlacements[joint].translation))
            joint = int(model.parents[joint])
    return bound


def resample(positions: np.ndarray, reach: np.ndarray, max_step_m: float = MAX_STEP_M) -> np.ndarray:
    """The path through `positions` (linear between them) at configurations between which no
    point moves more than `max_step_m`; the first and every waypoint included."""
    positions = np.asarray(positions, dtype=float)
    if len(positions) < 2:
        return positions.copy()
    delta = np.diff(positions, axis=0)
    moves = np.abs(delta) @ reach
    pieces = np.maximum(1, np.ceil(moves / max_step_m).astype(int))
    segment = np.repeat(np.arange(len(delta)), pieces)
    offsets = np.arange(int(pieces.sum())) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    alpha = offsets / pieces[segment]
    dense = positions[segment] + alpha[:, None] * delta[segment]
    return np.vstack([dense, positions[-1:]])


@dataclass
class PathReport:
    """What the dense check found on one path (or several, merged)."""

    geometry: str
    paths: int = 0
    samples: int = 0
    #: the smallest height above the table of any moving body, and which body [m]
    table_clearance_m: float = math.inf
    table_body: str = ""
    #: per zone, the smallest distance of any body (exact where within BROAD_MARGIN_M; else a lower bound)
    zone_clearance_m: dict[str, float] = field(default_factory=dict)
    #: one line per contact found (body, obstacle, sample), the first few
    contacts: list[str] = field(default_factory=list)
    contact_count: int = 0

    @property
    def clear(self) -> bool:
        return self.contact_count == 0

    def merge(self, other: PathReport) -> None:
        self.paths += other.paths
        self.samples += other.samples
        if other.table_clearance_m < self.table_clearance_m:
            self.table_clearance_m, self.table_body = other.table_clearance_m, other.table_body
        for name, value in other.zone_clearance_m.items():
            self.zone_clearance_m[name] = min(self.zone_clearance_m.get(name, math.inf), value)
        self.contacts += other.contacts[: max(0, 10 - len(self.contacts))]
        self.contact_count += other.contact_count

    def summary(self) -> str:
        zones = ", ".join(f"{name} {value * 1e3:.1f} mm" for name, value in sorted(self.zone_clearance_m.items()))
        return (f"{self.geometry}: {self.paths} paths, {self.samples} configurations, "
                f"{'clear' if self.clear else f'{self.contact_count} contacts'}; lowest body "
                f"{self.table_clearance_m * 1e3:.1f} mm above the table ({self.table_body}); zones: {zones}")


class DenseChecker:
    """Checks joint paths of the arm against the table and zones with one geometry."""

    def __init__(self, arm: ArmKinematics, geometry: Geometry, zones: Sequence[Zone],
                 table_z_m: float = 0.0, max_step_m: float = MAX_STEP_M) -> None:
        self.arm, self.geometry, self.zones = arm, geometry, tuple(zones)
        self.table_z_m, self.max_step_m = table_z_m, max_step_m
        self.reach = reach_bound(arm, geometry)
        bodies = geometry.bodies
        identity = len(arm.lower)  # the slot of an identity placement appended to the joints' (fixed bodies)
        self._body_slot = np.array([b.joint if b.joint >= 0 else identity for b in bodies])
        # the bodies' points grouped by joint slot: one matrix product per slot, no gathers
        self._by_slot = []
        for slot in sorted(set(self._body_slot.tolist())):
            members = np.flatnonzero(self._body_slot == slot)
            points = np.vstack([bodies[i].points for i in members])
            owner = np.concatenate([np.full(len(bodies[i].points), i) for i in members])
            self._by_slot.append((slot, members, np.hstack([points, np.ones((len(points), 1))]).T, owner))
        order = np.concatenate([owner for _, _, _, owner in self._by_slot])  # body of each point, in slot order
        self._point_order = np.argsort(order, kind="stable")  # slot order -> body order
        counts = np.bincount(order, minlength=len(bodies))
        self._starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        #: every body has this many points (capsules: 2): bounds by a reshape instead of `reduceat`
        self._same_count = int(counts[0]) if len(set(counts.tolist())) == 1 else 0
        self._radius = np.array([b.radius_m for b in bodies])
        self._on_table = np.array([b.link != BASE_LINK for b in bodies])
        self._zone_shapes = [z.shape() for z in self.zones]

    def check(self, positions: np.ndarray) -> PathReport:
        """The path through `positions` (rad, (K, 7), linear between them), densely."""
        dense = resample(positions, self.reach, self.max_step_m)
        report = PathReport(self.geometry.kind, paths=1, samples=len(dense),
                            zone_clearance_m={z.name: math.inf for z in self.zones})
        for start in range(0, len(dense), CHUNK):
            self._check_chunk(dense[start:start + CHUNK], start, report)
        return report

    def check_configuration(self, q: np.ndarray) -> PathReport:
        report = PathReport(self.geometry.kind, paths=1, samples=1, zone_clearance_m={z.name: math.inf for z in self.zones})
        self._check_chunk(np.asarray(q, dtype=float)[None], 0, report)
        return report

    def _check_chunk(self, qs: np.ndarray, offset: int, report: PathReport) -> None:
        joints = self.arm.joint_frames(qs)
        frames = np.concatenate([joints, np.broadcast_to(np.eye(4), (len(qs), 1, 4, 4))], axis=1)  # + identity
        # every point in the base frame, (N, 3, P) grouped by body; each body's bounds, widened by its radius
        world = np.concatenate([frames[:, slot, :3, :] @ points for slot, _, points, _ in self._by_slot], axis=2)
        world = world[:, :, self._point_order]
        widen = self._radius[None, None, :]
        if self._same_count:
            grouped = world.reshape(len(qs), 3, -1, self._same_count)
            lo, hi = grouped.min(axis=3) - widen, grouped.max(axis=3) + widen  # (N, 3, B)
        else:
            lo = np.minimum.reduceat(world, self._starts, axis=2) - widen
            hi = np.maximum.reduceat(world, self._starts, axis=2) + widen
        # table: the exact lowest point of each moving body (a capsule's lowest end less its
        # radius; a mesh's lowest vertex)
        lowest = np.where(self._on_table[None, :], lo[:, 2, :] - self.table_z_m, np.inf)  # (N, B)
        n, b = np.unravel_index(int(np.argmin(lowest)), lowest.shape)
        if lowest[n, b] < report.table_clearance_m:
            report.table_clearance_m = float(lowest[n, b])
            report.table_body = self.geometry.bodies[b].name
        for n, b in zip(*np.nonzero(lowest <= 0.0), strict=True):
            self._contact(report, f"{self.geometry.bodies[b].name} at {lowest[n, b] * 1e3:+.2f} mm "
                                  f"of the table (configuration {offset + n})")
        # zones: the bodies' bounds first, coal's exact answer for every body whose bounds come near
        for zone, (box, box_tf) in zip(self.zones, self._zone_shapes, strict=True):
            gap = np.maximum(np.maximum(zone.lo[None, :, None] - hi, lo - zone.hi[None, :, None]), 0.0)
            bound = np.sqrt(np.sum(gap * gap, axis=1))  # (N, B): a lower bound on each body's distance
            near = bound < BROAD_MARGIN_M
            figure = float(bound[~near].min()) if np.any(~near) else math.inf
            for n, b in np.argwhere(near):
                body = self.geometry.bodies[b]
                placement = frames[n, self._body_slot[b]]
                tf = coal.Transform3s(placement[:3, :3], placement[:3, 3]) * body.local
                if coal.collide(body.shape, tf, box, box_tf, coal.CollisionRequest(), coal.CollisionResult()):
                    figure = min(figure, 0.0)
                    self._contact(report, f"{body.name} in zone {zone.name!r} (configuration {offset + n})")
                    continue
                distance = coal.distance(body.shape, tf, box, box_tf, coal.DistanceRequest(), coal.DistanceResult())
                figure = min(figure, float(distance))
            report.zone_clearance_m[zone.name] = min(report.zone_clearance_m[zone.name], figure)

    @staticmethod
    def _contact(report: PathReport, text: str) -> None:
        report.contact_count += 1
        if len(report.contacts) < 10:
            report.contacts.append(text)


def merged(reports: Iterable[PathReport], kind: str) -> PathReport:
    total = PathReport(kind)
    for report in reports:
        total.merge(report)
    return total


# --------------------------------------------------------------------------- the mesh cache


def _fit_geometry_module():
    spec = importlib.util.spec_from_file_location("fit_geometry", ROOT / "scripts" / "fit_geometry.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("fit_geometry", module)  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def write_mesh_cache(source: Path, out: Path, revision: str | None = None) -> str:
    """Franka's collision meshes (links 0-7, hand, finger boxes) in ArmWarden's link frames, read
    from franka_description at the commit robots/fr3/fitted.yaml was fitted to (or `revision`), to `out`."""
    fit = _fit_geometry_module()
    revision = revision or load_fitted(FITTED).source.get("commit", "HEAD")
    src = fit.Source.open(source, revision)
    fit.check_kinematics(src, resolve_description("builtin:fr3"))
    arrays: dict[str, np.ndarray] = {"commit": np.array(src.commit or "(a work tree)")}
    for link, mesh in fit.load_links(src).items():
        turned = fit.transform_mesh(mesh, fit.FRANKA_TO_OURS.get(link, np.eye(3)), (0.0, 0.0, 0.0))
        arrays[f"{link}/vertices"] = np.asarray(turned.vertices, dtype=float)
        arrays[f"{link}/triangles"] = np.asarray(turned.triangles, dtype=np.int64)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **arrays)  # type: ignore[arg-type]
    return str(arrays["commit"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--source", type=Path, required=True, help="franka_description: a checkout or a git directory")
    parser.add_argument("--write-meshes", type=Path, default=MESH_CACHE, metavar="FILE")
    parser.add_argument("--commit", default=None, help="revision to read (default: the one robots/fr3/fitted.yaml names)")
    args = parser.parse_args(argv)
    commit = write_mesh_cache(args.source, args.write_meshes, args.commit)
    print(f"wrote {args.write_meshes} (franka_description at {commit})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
