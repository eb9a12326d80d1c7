"""Which part of a description is the arm: its base, its joints in order, its TCP, and the rest.

`armwarden init` infers them where the description leaves one answer and otherwise names the
candidates and the flag that picks one. The arm is the longest chain of revolute joints from the
root (joints named for a finger, gripper, jaw or claw and joints that mimic another are never arm
joints); its base is the link its first joint is mounted on (not a `world` root below it); its
TCP the one frame rigidly attached at the chain's far end (e.g. a `tool0`), or of several there,
the one named as a tool point (tcp, tool, ee, eef, end_effector). Every other independent joint (fingers, a jaw) is a gripper joint.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError

#: the fewest and most arm joints ArmWarden drives
MIN_ARM_JOINTS, MAX_ARM_JOINTS = 4, 7
#: names that say a joint moves a gripper, not the arm
GRIPPER_NAME = re.compile(r"finger|gripper|jaw|claw", re.IGNORECASE)
#: names that say a frame is the tool point, preferred when several frames end the arm
TCP_NAME = re.compile(r"tcp|tool|end_?effector|(^|_)eef?($|_)", re.IGNORECASE)


@dataclass(frozen=True)
class Chain:
    """The arm in a description: frames and joints by name, joints in kinematic order."""

    base_frame: str
    tcp_frame: str
    joint_names: tuple[str, ...]
    gripper_joints: tuple[str, ...]


def _is_revolute(model: pin.Model, joint: int) -> bool:
    name = model.joints[joint].shortname()
    return name.startswith(("JointModelR", "JointModelRevolute"))


def _path_from_root(model: pin.Model, joint: int) -> list[int]:
    path = []
    while joint > 0:
        path.append(joint)
        joint = int(model.parents[joint])
    return path[::-1]


def _longest_chain(model: pin.Model, excluded: Collection[str]) -> list[int]:
    arm = {j for j in range(1, model.njoints) if _is_revolute(model, j) and not GRIPPER_NAME.search(model.names[j])
           and model.names[j] not in excluded}
    paths = [_path_from_root(model, j) for j in sorted(arm)]
    chains = [path for path in paths if all(k in arm for k in path)]
    if not chains:
        raise RobotModelError("the description has no chain of revolute joints from its root; name the arm's joints "
                              "with --joints")
    longest = max(len(c) for c in chains)
    ends = sorted({c[-1] for c in chains if len(c) == longest})
    if len(ends) > 1:
        raise RobotModelError(f"the description has {len(ends)} revolute chains of {longest} joints, ending at "
                              + ", ".join(model.names[j] for j in ends) + "; name the arm's joints with --joints")
    return next(c for c in chains if c[-1] == ends[0])


def _checked_joints(model: pin.Model, joints: Sequence[str]) -> list[int]:
    names = list(model.names)[1:]
    unknown = [j for j in joints if j not in names]
    if unknown:
        raise RobotModelError(f"unknown joint(s) {', '.join(unknown)}; the description's joints: {', '.join(names)}")
    ids = [int(model.getJointId(j)) for j in joints]
    if len(set(ids)) != len(ids):
        raise RobotModelError(f"a joint is named twice in {', '.join(joints)}")
    path = _path_from_root(model, ids[-1])
    if [j for j in path if j in ids] != ids:
        order = [model.names[j] for j in path if j in ids]
        raise RobotModelError(f"the joints {', '.join(joints)} are not one chain in kinematic order"
                              + (f" (in order: {', '.join(order)})" if len(order) == len(ids) else ""))
    between = [model.names[j] for j in path if j not in ids]
    if between:  # locked at zero, it would move the real arm's base while the checks think it fixed
        raise RobotModelError(f"joint(s) {', '.join(between)} move the arm's base but are not among --joints; "
                              "the arm's joints are every joint from its fixed base to its TCP")
    for j in ids:
        if not _is_revolute(model, j):
            raise RobotModelError(f"joint {model.names[j]} is not revolute; ArmWarden's arm joints are revolute")
    return ids


def _root_link(model: pin.Model, first_joint: int) -> str:
    """The link the arm's first joint is mounted on: in a cell description (`world` → a fixed joint
    0.8 m up → `link0`) that is `link0`, whose plane is the table the arm stands on, not the floor."""
    frame = model.frames[model.getFrameId(model.names[first_joint], pin.FrameType.JOINT)]
    while True:
        parent = model.frames[frame.parentFrame]
        if parent.type == pin.FrameType.BODY and parent.name != "universe":
            return parent.name
        if frame.parentFrame == 0:
            raise RobotModelError("the description has no link before its first arm joint; give --base-frame")
        frame = parent


def _tcp_candidates(model: pin.Model, last_joint: int, *, leaves: bool = True) -> list[str]:
    """The frames rigidly on the last joint's link that nothing else rigid hangs from (all of them
    when not `leaves`)."""
    kinds = (pin.FrameType.BODY, pin.FrameType.OP_FRAME)
    on_link = [i for i, f in enumerate(model.frames) if f.type in kinds and f.parentJoint == last_joint]
    ancestors: set[int] = set()
    for i in on_link:
        parent = model.frames[i].parentFrame
        while parent != 0 and model.frames[parent].parentJoint == last_joint:
            ancestors.add(parent)
            parent = model.frames[parent].parentFrame
    return [model.frames[i].name for i in on_link if not leaves or i not in ancestors]


def infer_chain(model: pin.Model, *, base_frame: str | None = None, tcp_frame: str | None = None,
                joints: Sequence[str] | None = None, mimic_joints: Collection[str] = ()) -> Chain:
    """The arm in `model`; each of `base_frame`, `tcp_frame`, `joints` given is checked instead of inferred."""
    ids = _checked_joints(model, joints) if joints else _longest_chain(model, mimic_joints)
    names = tuple(model.names[j] for j in ids)
    if not MIN_ARM_JOINTS <= len(ids) <= MAX_ARM_JOINTS:
        raise RobotModelError(f"the arm has {len(ids)} joints ({', '.join(names)}); ArmWarden drives arms of "
                              f"{MIN_ARM_JOINTS} to {MAX_ARM_JOINTS} joints (choose them with --joints)")
    frames = [f.name for f in model.frames if f.name != "universe"]
    if base_frame is None:
        base_frame = _root_link(model, ids[0])
    elif base_frame not in frames:
        raise RobotModelError(f"base frame {base_frame!r} is unknown; the description's frames: {', '.join(frames)}")
    elif model.frames[model.getFrameId(base_frame)].parentJoint != 0:
        raise RobotModelError(f"base frame {base_frame!r} moves with a joint; the base must be fixed to the world")
    if tcp_frame is None:
        candidates = _tcp_candidates(model, ids[-1])
        named = [c for c in candidates if TCP_NAME.search(c)]
        if len(candidates) > 1 and len(named) == 1:  # e.g. xArm's link_tcp beside its fixed finger links
            candidates = named
        if len(candidates) != 1:
            raise RobotModelError(f"the TCP frame is ambiguous: {', '.join(candidates)} are all at the end of the arm; "
                                  "choose one with --tcp-frame")
        tcp_frame = candidates[0]
    elif tcp_frame not in frames:
        raise RobotModelError(f"TCP frame {tcp_frame!r} is unknown; the description's frames: {', '.join(frames)}")
    elif model.frames[model.getFrameId(tcp_frame)].parentJoint != ids[-1]:
        raise RobotModelError(f"TCP frame {tcp_frame!r} is not rigidly attached after the arm's last joint "
                              f"{names[-1]}; frames that are: {', '.join(_tcp_candidates(model, ids[-1], leaves=False))}")
    gripper = tuple(model.names[j] for j in range(1, model.njoints)
                    if j not in ids and model.names[j] not in mimic_joints)
    return Chain(base_frame, tcp_frame, names, gripper)


__all__ = ["GRIPPER_NAME", "MAX_ARM_JOINTS", "MIN_ARM_JOINTS", "TCP_NAME", "Chain", "infer_chain"]
