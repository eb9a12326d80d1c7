"""`run_init`: the steps of `armwarden init`, in order, each one's result checked before the next."""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import yaml

from armwarden.core.errors import RobotModelError
from armwarden.onboarding.checks import refuse_mjcf_misread, refuse_overwriting, refuse_stale_fit, refuse_uncovered_links
from armwarden.onboarding.fitted import FitSettings, finger_joints, fit_arm, fitted_header
from armwarden.onboarding.home import choose_home
from armwarden.onboarding.limits import joint_limits
from armwarden.onboarding.picture import home_picture
from armwarden.onboarding.policy_text import LINK_PADDING_M, GripperDraft, PolicyDraft, render_policy
from armwarden.onboarding.reach import Workspace, derive_workspace
from armwarden.policy import Policy, load_policy, parse_policy
from armwarden.policy.devices import MAX_GRIPPER_WIDTH_M
from armwarden.policy.fields import MAX_COORDINATE_M
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.robot import build_robot
from armwarden.robot.description_chain import Chain, infer_chain
from armwarden.robot.description_files import Description, load_description
from armwarden.robot.fitted_file import load_fitted, render_fitted
from armwarden.robot.link_meshes import link_meshes
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import EnvelopeLimits


@dataclass(frozen=True)
class InitOptions:
    """What `armwarden init` was asked (paths as the user gave them)."""

    description: Path
    output: Path
    base_frame: str | None = None
    tcp_frame: str | None = None
    joints: tuple[str, ...] | None = None
    mesh_paths: tuple[Path, ...] = ()
    name: str | None = None
    fit: FitSettings = field(default_factory=FitSettings)
    #: a robot folder shipped with ArmWarden: the policy names its files `builtin:<builtin>`
    builtin: str | None = None
    #: fitted geometry made before for this very description (its SHA-256 checked): not fitted again
    fitted: Path | None = None

    @property
    def fitted_path(self) -> Path:
        return self.output.with_name(f"{self.output.stem}.fitted.yaml")

    @property
    def picture_path(self) -> Path:
        return self.output.with_name(f"{self.output.stem}.home.png")


@dataclass(frozen=True)
class InitResult:
    """What was written, and the checked policy it holds."""

    policy_path: Path
    fitted_path: Path
    picture_path: Path | None  # None: Pillow missing, no picture
    runtime: RuntimeModel
    chain: Chain
    workspace: Workspace
    gripper: GripperDraft | None
    notes: tuple[str, ...]


def _relative(path: Path, folder: Path) -> str:
    return Path(os.path.relpath(path.resolve(), folder.resolve())).as_posix()


def _scalar(text: str) -> str:
    """`text` as a YAML scalar: plain when that reads back unchanged, else quoted."""
    return text if re.fullmatch(r"[A-Za-z0-9_./-]+", text) else json.dumps(text)


def _robot_name(model: pin.Model, description: Path) -> str:
    name = re.sub(r"\s+", "_", model.name.strip()) or description.stem
    return name[:128]


def remake_command(options: InitOptions) -> list[str]:
    """The command that remakes these files, paths relative to the policy's folder (the header's).
    `--fitted` is left out: it reuses what this command makes."""
    folder = options.output.parent
    command = ["armwarden", "init", _relative(options.description, folder), "--output", options.output.name]
    for flag, value in (("--base-frame", options.base_frame), ("--tcp-frame", options.tcp_frame),
                        ("--joints", ",".join(options.joints) if options.joints else None)):
        if value:
            command += [flag, value]
    for path in options.mesh_paths:
        command += ["--mesh-path", str(path)]  # as given: where the meshes were is the user's business
    defaults = FitSettings()
    if options.fit.max_bodies != defaults.max_bodies:
        command += ["--max-bodies", str(options.fit.max_bodies)]
    if options.builtin:
        command += ["--builtin", options.builtin]
    return command


def _fingers(model: pin.Model, chain: Chain) -> tuple[GripperDraft | None, list[str]]:
    """Prismatic joints besides the arm's are fingers: the opening is their summed travel. A revolute
    jaw has no width the gripper tools could command: no gripper section, and a note says so."""
    prismatic = finger_joints(model, chain.joint_names)
    other = [j for j in range(1, model.njoints) if model.names[j] not in chain.joint_names and j not in prismatic]
    notes = [f"joint {model.names[j]} is not an arm joint and not a prismatic finger: held at 0, no gripper tools "
             "for it" for j in other]
    if not prismatic:
        return None, notes
    travel = sum(float(model.upperPositionLimit[model.joints[j].idx_q] - model.lowerPositionLimit[model.joints[j].idx_q])
                 for j in prismatic)
    width = round(min(travel, MAX_GRIPPER_WIDTH_M), 6)
    return GripperDraft(tuple(model.names[j] for j in prismatic), width), notes


def _fitted_text(options: InitOptions, description: Description, name: str, arm_joints: tuple[str, ...],
                 progress: Callable[[str], None], notes: list[str]) -> str:
    """The fitted file: fitted now, or the one given (`options.fitted`) when it was made for this
    description and, where its meshes are here, for today's link surfaces."""
    digest = hashlib.sha256(options.description.read_bytes()).hexdigest()
    if options.fitted is not None:
        made = load_fitted(options.fitted)
        if made.source.get("sha256") != digest:
            raise RobotModelError(f"{options.fitted} was fitted to another description (SHA-256 "
                                  f"{made.source.get('sha256', 'not recorded')}, {options.description} is {digest}): "
                                  "run init without --fitted")
        try:
            surfaces = link_meshes(load_description(options.description, options.mesh_paths))
        except RobotModelError as exc:  # meshes not here: the description's digest is all that can be checked
            notes.append(f"--fitted: the link surfaces could not be re-checked against {options.fitted} ({exc})")
        else:
            refuse_stale_fit(made, surfaces)
        return options.fitted.read_text(encoding="utf-8")
    refuse_uncovered_links(description)
    meshes = link_meshes(description)
    refuse_mjcf_misread(description, meshes)
    if not meshes:
        raise RobotModelError(f"{options.description} has no collision geometry to fit: add <collision> shapes or "
                              "meshes to its links (give --mesh-path for package:// meshes)")
    geometry = fit_arm(description.model, meshes, robot=name, settings=options.fit, progress=progress,
                       source={"description": _relative(options.description, options.output.parent), "sha256": digest},
                       arm_joints=arm_joints)
    return render_fitted(geometry, fitted_header(name, options.description.name, options.fit, remake_command(options)))


def run_init(options: InitOptions, progress: Callable[[str], None] = lambda _: None) -> InitResult:
    """Generate, check and write the policy, its fitted geometry and the picture (see the package doc)."""
    refuse_overwriting(options.description, (options.output, options.fitted_path, options.picture_path))
    description = load_description(options.description, options.mesh_paths, with_collision=options.fitted is None)
    chain = infer_chain(description.model, base_frame=options.base_frame, tcp_frame=options.tcp_frame,
                        joints=options.joints, mimic_joints=description.mimic_joints)
    progress(f"arm: {len(chain.joint_names)} joints {', '.join(chain.joint_names)}; base {chain.base_frame}, "
             f"TCP {chain.tcp_frame}")
    joints = joint_limits(description.model, chain.joint_names)
    name = options.name or _robot_name(description.model, options.description)
    notes: list[str] = []
    fitted_text = _fitted_text(options, description, name, chain.joint_names, progress, notes)
    command = remake_command(options)
    gripper, finger_notes = _fingers(description.model, chain)
    notes += finger_notes
    lower, upper = np.array([j.min for j in joints]), np.array([j.max for j in joints])
    far = MAX_COORDINATE_M
    provisional = Workspace((-far, -far, -far), (far, far, far), 0.0, False)  # until the reach is known
    draft = PolicyDraft(
        name=name, source_label=options.description.name,
        description=_scalar(_relative(options.description, options.output.parent)),
        collision_geometry=_scalar(options.fitted_path.name),
        base_frame=chain.base_frame, tcp_frame=chain.tcp_frame, joints=joints, home=(lower + upper) / 2.0,
        workspace=provisional, gripper=gripper, command=command)
    if options.builtin:  # a shipped robot folder: its profile names the description and the fitted file
        draft = replace(draft, description=f"builtin:{options.builtin}", collision_geometry=f"builtin:{options.builtin}")
    with tempfile.TemporaryDirectory(prefix="armwarden-init-") as scratch:  # nothing is written until all is checked
        scratch_fitted = Path(scratch) / options.fitted_path.name
        scratch_fitted.write_text(fitted_text, encoding="utf-8")
        absolute = {"description": _scalar(str(options.description.resolve())), "collision_geometry": _scalar(str(scratch_fitted))}

        def checked(candidate: PolicyDraft) -> Policy:
            text = render_policy(replace(candidate, **absolute))
            return parse_policy(yaml.safe_load(text), source=str(options.output))

        workspace = derive_workspace(build_robot(checked(draft)), LINK_PADDING_M)
        draft = replace(draft, workspace=workspace)
        policy = checked(draft)
        envelope = Envelope(build_robot(policy), EnvelopeLimits.from_policy(policy))
        draft = replace(draft, home=choose_home(envelope, workspace.reach_m, workspace.table_z_m))
        load_runtime_model(checked(draft), str(options.output))  # what check-policy and serve run
    options.output.parent.mkdir(parents=True, exist_ok=True)
    options.fitted_path.write_text(fitted_text, encoding="utf-8")
    options.output.write_text(render_policy(draft), encoding="utf-8")
    runtime = load_runtime_model(load_policy(options.output), str(options.output))  # as written, from the disk
    picture = home_picture(runtime.envelope, draft.home)
    if picture is not None:
        options.picture_path.write_bytes(picture)
    if workspace.table_lowered:
        notes.append(f"a moving link reaches below the base: the table plane is at z = {workspace.table_z_m:g} m")
    return InitResult(options.output, options.fitted_path, options.picture_path if picture is not None else None,
                      runtime, chain, workspace, gripper, tuple(notes))


def summary(result: InitResult) -> list[str]:
    """What `armwarden init` prints: the arm, its geometry, home, workspace, files and what to review."""
    robot, policy = result.runtime.robot, result.runtime.policy
    home = np.array(policy.robot.home_joint_positions)
    tcp = robot.tcp_pose(home).position
    ws = result.workspace
    lines = [
        f"robot {policy.robot.name}: {robot.nq} joints ({', '.join(robot.joint_names)}), base {policy.robot.base_frame}, "
        f"TCP {policy.robot.tcp_frame}",
        f"collision: {len(robot.capsules)} capsules on {len({c.link for c in robot.capsules})} links, "
        f"{len(result.runtime.envelope.self_collision_pairs)} self-collision pairs checked",
        "home: [" + ", ".join(f"{v:.3f}" for v in home) + f"] rad, TCP at ({tcp[0]:.3f}, {tcp[1]:.3f}, {tcp[2]:.3f}) m",
        f"workspace: box {list(ws.box_min)} .. {list(ws.box_max)} m (reach {ws.reach_m:.3f} m), table z = "
        f"{ws.table_z_m:g} m",
        "gripper: " + (f"{', '.join(result.gripper.joints)}, opening 0..{result.gripper.max_width_m:g} m"
                       if result.gripper else "none"),
        *[f"note: {note}" for note in result.notes],
        f"wrote {result.policy_path}, {result.fitted_path}" + (f", {result.picture_path}" if result.picture_path else ""),
        "next: review the lines marked REVIEW, then `armwarden check-policy` and "
        f"`armwarden serve --policy {result.policy_path} --backend mujoco`",
    ]
    return lines


__all__ = ["InitOptions", "InitResult", "remake_command", "run_init", "summary"]


