"""The fitted collision capsules of a robot, placed on the joints of the policy's reduced model.

A fitted-geometry file (`armwarden.robot.fitted_file`, e.g. `robots/fr3/fitted.yaml`) holds
capsules per link, in the link's frame, and the self-collision pair analysis made over stated
joint limits. The envelope needs each capsule in the frame of the *driven* joint that moves it
(`Capsule`), and the body pairs it must check. Three things happen on the way:

- **Fixed links stay.** Bodies on a link fixed to the world (the FR3's base, link 0) are kept on
  joint 0: nothing moves them, so the workspace and keep-out checks skip them, but the arm must
  not fold into them, so they take part in self-collision.
- **Locked prismatic joints are swept.** The policy drives the arm joints only; a link behind a
  locked prismatic joint (a gripper finger) can be anywhere along that joint's range. Each of its
  capsules becomes one capsule holding it at every position: the segment from its centre at the
  lower limit to its centre at the upper limit, radius grown by half its own length (every point
  of the body lies within radius + half length of its centre, and the centre lies on that
  segment). A link behind a locked *revolute* joint, or behind more than one locked joint, is
  refused: its sweep is not a capsule.
- **Pairs by proof.** Every pair of bodies on different links is checked unless the file lists it
  as excluded with a proof (`armwarden.robot.pairs`), or both bodies ride on the same driven
  joint (the hand and its fingers): no arm motion changes where they are relative to each other,
  so no plan can bring them into contact — how far the fingers close is the gripper's limit, not
  the envelope's. The proofs hold over the file's joint limits only; `require_limits_within`
  refuses a file analysed over narrower limits than the policy's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.robot.capsules import Capsule
from armwarden.robot.fitted_file import FittedGeometry

__all__ = ["fitted_capsules", "fitted_pairs", "require_limits_within"]


def _body_frame(model: pin.Model, link: str, role: str) -> pin.Frame:
    if not model.existFrame(link, pin.FrameType.BODY):
        raise RobotModelError(f"fitted collision geometry names link {link!r}, which is not a link of the {role}")
    return model.frames[model.getFrameId(link, pin.FrameType.BODY)]


def _locked_chain(full: pin.Model, link: str, driven_parent: str) -> list[int]:
    """Joints of the full model between `link` and the driven joint named `driven_parent` (the
    reduced model's parent joint of the link): the locked joints that move it."""
    joint = int(_body_frame(full, link, "description").parentJoint)
    locked = []
    while joint > 0 and full.names[joint] != driven_parent:
        locked.append(joint)
        joint = int(full.parents[joint])
    return locked


def _placement_in(full: pin.Model, link: str, parent_joint: str, q: np.ndarray) -> pin.SE3:
    """The link's frame in `parent_joint`'s frame (or the world's, for the universe) at `q`."""
    data = full.createData()
    pin.forwardKinematics(full, data, q)
    pin.updateFramePlacements(full, data)
    world_link = data.oMf[full.getFrameId(link, pin.FrameType.BODY)]
    if parent_joint == "universe":
        return world_link
    return data.oMi[full.getJointId(parent_joint)].actInv(world_link)


def fitted_capsules(full: pin.Model, reduced: pin.Model, geometry: FittedGeometry,
                    reference: np.ndarray) -> tuple[Capsule, ...]:
    """Every fitted body as a `Capsule` on the reduced model's joint that moves it.

    `full` is the description's model before the non-driven joints were locked, `reference` its
    configuration at which they were locked (`RobotModel` locks at `reference`)."""
    capsules: list[Capsule] = []
    for link, fit in geometry.links.items():
        frame = _body_frame(reduced, link, "policy's robot model")
        joint = int(frame.parentJoint)
        parent_name = str(reduced.names[joint])
        locked = _locked_chain(full, link, parent_name)
        if not locked:
            for body in fit.bodies:
                p0 = frame.placement.act(np.array(body.p0_m, dtype=float))
                p1 = frame.placement.act(np.array(body.p1_m, dtype=float))
                capsules.append(_capsule(body.name, link, joint, p0, p1, body.radius_m))
            continue
        if len(locked) > 1 or "JointModelP" not in full.joints[locked[0]].shortname():
            names = [str(full.names[j]) for j in locked]
            raise RobotModelError(
                f"fitted link {link!r} moves with locked joint(s) {names}; only one locked prismatic joint (a "
                "gripper finger) can be swept into capsules. Drive those joints, or fit that link's geometry to "
                "cover its whole motion"
            )
        locked_joint = full.joints[locked[0]]
        lo_q, hi_q = reference.copy(), reference.copy()
        lo_q[locked_joint.idx_q] = full.lowerPositionLimit[locked_joint.idx_q]
        hi_q[locked_joint.idx_q] = full.upperPositionLimit[locked_joint.idx_q]
        at_lo = _placement_in(full, link, parent_name, lo_q)
        at_hi = _placement_in(full, link, parent_name, hi_q)
        for body in fit.bodies:
            p0, p1 = np.array(body.p0_m, dtype=float), np.array(body.p1_m, dtype=float)
            centre = (p0 + p1) / 2.0
            grown = body.radius_m + float(np.linalg.norm(p1 - p0)) / 2.0
            capsules.append(_capsule(body.name, link, joint, at_lo.act(centre), at_hi.act(centre), grown))
    return tuple(capsules)


def _capsule(name: str, link: str, joint: int, p0: np.ndarray, p1: np.ndarray, radius: float) -> Capsule:
    return Capsule(
        name=name,
        link=link,
        joint_index=joint,
        p0_m=(float(p0[0]), float(p0[1]), float(p0[2])),
        p1_m=(float(p1[0]), float(p1[1]), float(p1[2])),
        radius_m=float(radius),
    )


def fitted_pairs(capsules: Sequence[Capsule], geometry: FittedGeometry) -> np.ndarray:
    """(P, 2) capsule index pairs to check: every pair on different links and driven joints that
    the file does not exclude with a proof. A file without a pair analysis is refused: its overlapping neighbours
    would refuse every motion, and guessing which to drop is what the analysis replaces."""
    if not geometry.joint_limits:
        raise RobotModelError("the fitted collision geometry has no self-collision pair analysis (`pairs:`)")
    excluded = {frozenset(e.bodies) for e in geometry.excluded_pairs}
    pairs = [
        (a, b)
        for a in range(len(capsules))
        for b in range(a + 1, len(capsules))
        if capsules[a].link != capsules[b].link
        and capsules[a].joint_index != capsules[b].joint_index
        and frozenset((capsules[a].name, capsules[b].name)) not in excluded
    ]
    return np.array(pairs, dtype=np.intp).reshape(-1, 2)


def require_limits_within(geometry: FittedGeometry, limits: Mapping[str, tuple[float, float]], tolerance: float = 1e-6) -> None:
    """Refuse joint limits wider than those the pair analysis was proved over (or a joint it did
    not cover): an excluded pair's proof says nothing outside them."""
    wider = []
    for name, (lo, hi) in limits.items():
        proved = geometry.joint_limits.get(name)
        if proved is None or lo < proved[0] - tolerance or hi > proved[1] + tolerance:
            wider.append(f"{name} [{lo:g}, {hi:g}] (analysed: {'none' if proved is None else list(proved)})")
    if wider:
        raise RobotModelError(
            "joint limits wider than the self-collision pair analysis of the fitted geometry covers: "
            + "; ".join(wider)
            + ". Narrow the limits, or re-run the analysis (scripts/fit_geometry.py --pairs-only) over them"
        )
