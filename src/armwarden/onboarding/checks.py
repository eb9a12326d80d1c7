"""What init refuses before fitting, because the policy would otherwise be less safe than it says.

- The output must not overwrite the description.
- A moving URDF link with visual geometry but no collision geometry would get no capsule, and so
  never be checked against the table, the workspace, keep-out zones or the other links.
- An MJCF file is read by Pinocchio, whose reader leaves out some of MJCF (mesh scales given in
  `<default>`, `<frame>` elements, a joint's `ref`): MuJoCo compiles the same file, and every body,
  every hinge's limits and every body's collision extent must agree, or init refuses naming the
  difference.
- Fitted geometry reused with `--fitted` must hold today's link surfaces where the meshes are here.
"""

# mujoco ships compiled pybind11 modules without type stubs (as backends/mujoco/model.py says)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.onboarding.fitted import vertices_digest
from armwarden.robot.description_files import Description
from armwarden.robot.fitted_file import FittedGeometry
from armwarden.robot.fitting_mesh import LinkMesh

#: [m] how far MuJoCo's and Pinocchio's collision extent of one body may differ
EXTENT_TOLERANCE_M = 1e-4


def refuse_overwriting(description: Path, outputs: tuple[Path, ...]) -> None:
    source = description.resolve()
    for output in outputs:
        if output.resolve() == source:
            raise RobotModelError(f"{output} is the description itself: choose another --output (init would "
                                  "overwrite the arm's description)")


def refuse_uncovered_links(description: Description) -> None:
    """A moving URDF link that has a visual shape but no collision shape: refused, named."""
    if description.kind != "urdf":
        return
    model = description.model
    moving = {f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint > 0}
    root = ET.parse(description.path).getroot()
    bare = [str(link.get("name")) for link in root.iter("link")
            if link.get("name") in moving and link.find("visual") is not None and link.find("collision") is None]
    if bare:
        raise RobotModelError(f"moving link(s) {', '.join(bare)} have a visual shape but no collision shape: the "
                              "envelope would never check them; add <collision> to each (a box or cylinder around the "
                              "part will do, init fits capsules to it)")


def refuse_stale_fit(fitted: FittedGeometry, surfaces: Mapping[str, LinkMesh]) -> None:
    """Every link surface of today must be the one the reused fit recorded (its vertex digest)."""
    changed = [link for link, fit in fitted.links.items()
               if link in surfaces and fit.vertices_sha256 and vertices_digest(surfaces[link]) != fit.vertices_sha256]
    missing = [link for link in surfaces if link not in fitted.links]
    if changed or missing:
        raise RobotModelError("the fitted file does not hold today's link surfaces (changed: "
                              f"{', '.join(changed) or 'none'}; not fitted: {', '.join(missing) or 'none'}): run "
                              "init without --fitted")


def _collision_extents_mujoco(model: object) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    extents: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    for g in range(model.ngeom):
        if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
            continue
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.geom_bodyid[g])
        if model.geom_bodyid[g] == 0:  # the world's (a floor)
            continue
        # int(): a numpy int is not found `in` a tuple of MuJoCo's enums
        if int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_MESH):  # the mesh's own vertices, its geom's frame
            mesh = model.geom_dataid[g]
            local = model.mesh_vert[model.mesh_vertadr[mesh]:model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
        else:  # a primitive: the corners of its box (round ones: a little beyond them)
            centre, half = model.geom_aabb[g][:3], model.geom_aabb[g][3:]
            local = centre + signs * half
        corners = local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        lo, hi = extents.get(body, (np.full(3, np.inf), np.full(3, -np.inf)))
        extents[body] = (np.minimum(lo, corners.min(axis=0)), np.maximum(hi, corners.max(axis=0)))
    return extents


def refuse_mjcf_misread(description: Description, surfaces: Mapping[str, LinkMesh]) -> None:
    """MuJoCo's compile of the MJCF against Pinocchio's reading: bodies, hinge limits and `ref`, and
    each body's collision extent at the zero configuration (a box around the surfaces)."""
    if description.kind != "mjcf":
        return
    import mujoco

    try:
        compiled = mujoco.MjModel.from_xml_path(str(description.path))
    except Exception as exc:  # MuJoCo's own parser text
        raise RobotModelError(f"MuJoCo cannot compile {description.path}: {exc}") from exc
    model = description.model
    bodies = {mujoco.mj_id2name(compiled, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, compiled.nbody)}
    frames = {f.name for f in model.frames if f.type == pin.FrameType.BODY}
    lost = sorted(b for b in bodies if b and b not in frames)
    if lost:
        raise RobotModelError(f"Pinocchio's reading of {description.path} lacks the bodies {', '.join(lost)} that MuJoCo "
                              "compiles (e.g. inside a <frame> element): move them out of the <frame>")
    problems = []
    for j in range(compiled.njnt):
        name = mujoco.mj_id2name(compiled, mujoco.mjtObj.mjOBJ_JOINT, j)
        if int(compiled.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)) or not name:
            continue
        if abs(float(compiled.qpos0[compiled.jnt_qposadr[j]])) > 1e-12:
            problems.append(f"joint {name} has ref {float(compiled.qpos0[compiled.jnt_qposadr[j]]):g} (not read alike)")
            continue
        if compiled.jnt_limited[j] and model.existJointName(name):
            idx = model.joints[model.getJointId(name)].idx_q
            mine = (float(model.lowerPositionLimit[idx]), float(model.upperPositionLimit[idx]))
            theirs = tuple(float(v) for v in compiled.jnt_range[j])
            if max(abs(mine[0] - theirs[0]), abs(mine[1] - theirs[1])) > 1e-9:
                problems.append(f"joint {name}: limits {mine} read, MuJoCo compiles {theirs}")
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    for body, (lo, hi) in _collision_extents_mujoco(compiled).items():
        surface = surfaces.get(body)
        if surface is None:
            problems.append(f"body {body}: MuJoCo has collision geometry, Pinocchio's reading none")
            continue
        placement = data.oMf[model.getFrameId(body, pin.FrameType.BODY)]
        points = surface.vertices @ placement.rotation.T + placement.translation
        # boxes around turned round primitives reach a little past the shapes, and the surfaces that
        # enclose round primitives a little past them: a tenth of the body's size either way is
        # slack; a mesh scale or a dropped shape differs by far more
        slack = 0.1 * float(np.max(hi - lo)) + EXTENT_TOLERANCE_M
        short = np.max(np.maximum(points.min(axis=0) - lo, hi - points.max(axis=0)))
        beyond = np.max(np.maximum(lo - points.min(axis=0), points.max(axis=0) - hi))
        if short > slack or beyond > slack:
            problems.append(f"body {body}: collision extent {np.round(points.min(axis=0), 4).tolist()}.."
                            f"{np.round(points.max(axis=0), 4).tolist()} read, MuJoCo compiles "
                            f"{np.round(lo, 4).tolist()}..{np.round(hi, 4).tolist()}")
    if problems:
        raise RobotModelError(f"Pinocchio reads {description.path} differently from MuJoCo (a mesh scale set in "
                              "<default>, a <frame>, a joint's ref): " + "; ".join(problems))


__all__ = ["EXTENT_TOLERANCE_M", "refuse_mjcf_misread", "refuse_overwriting", "refuse_stale_fit",
           "refuse_uncovered_links"]
