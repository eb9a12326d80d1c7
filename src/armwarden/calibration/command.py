"""The `armwarden calibrate-contact` subcommand: what it asks the human, what it prints and writes.

On a terminal it lists what will move (how many motions, each joint's range, its top speed and
acceleration) and waits for `yes`; `--yes` answers for simulation and CI; with neither (no
terminal) it refuses (exit 2) and nothing moves. The recommended section goes to `--output` or
stdout as YAML, the per-joint summary (residual seen, limit, false-alarm margin) to stderr. The
user's policy file is never edited: they paste the section after reading it. A stop, an e-stop,
a contact or a refusal during the motions ends the calibration with nothing recommended (exit 1).
"""

from __future__ import annotations

import argparse
import getpass
import math
import sys
from typing import TextIO

import anyio
import numpy as np
import yaml

from armwarden.audit import AuditWriteError
from armwarden.calibration.arguments import add_calibrate_arguments
from armwarden.calibration.friction_fit import MIN_LIMIT_NM, JointRecommendation
from armwarden.calibration.run import CalibrationOptions, CalibrationResult, calibration_goals, run_calibration
from armwarden.consent import confirmed
from armwarden.core.errors import ArmWardenError
from armwarden.policy import Policy, load_policy
from armwarden.policy.joint_torques import MAX_EXTERNAL_TORQUE_NM

EXIT_OK, EXIT_STOPPED, EXIT_REFUSED = 0, 1, 2

__all__ = ["EXIT_OK", "EXIT_REFUSED", "EXIT_STOPPED", "add_calibrate_arguments", "calibrate_command",
           "render_section", "render_summary"]


def what_moves(policy: Policy, args: argparse.Namespace) -> str:
    """What the human approves: the backend, the number of motions, each joint's range over all the
    goals (home among them) and its top speed and acceleration at the policy's largest scalings."""
    motion = policy.motion
    goals = np.array(calibration_goals(policy, args.motions, args.seed))
    lines = [f"calibrate-contact will move the arm ({policy.robot.name}, backend {args.backend}) through "
             f"{args.motions} seeded random motions (seed {args.seed}) and back home, each planned and checked by "
             "the envelope, monitored for contact and audited, at the policy's largest scalings "
             f"({motion.max_velocity_scaling:g} of each joint's velocity, {motion.max_acceleration_scaling:g} of its "
             "acceleration limit):"]
    for j, (name, limit) in enumerate(policy.robot.joint_limits.items()):
        lines.append(f"  {name}: {goals[:, j].min():+.2f} .. {goals[:, j].max():+.2f} rad, up to "
                     f"{limit.max_velocity * motion.max_velocity_scaling:.2f} rad/s and "
                     f"{limit.max_acceleration * motion.max_acceleration_scaling:.2f} rad/s²")
    lines.append("Keep the cell clear and the e-stop in reach; Ctrl-C or SIGUSR1 latches the e-stop and ends it.")
    return "\n".join(lines)


def _approved(policy: Policy, args: argparse.Namespace, stdin: TextIO, stderr: TextIO) -> bool:
    return confirmed(what_moves(policy, args), assume_yes=args.yes, command="armwarden calibrate-contact",
                     stdin=stdin, stderr=stderr)


def _margin_text(r: JointRecommendation) -> str:
    return "no residual" if math.isinf(r.margin) else f"{r.margin:.1f}x margin"


def render_section(result: CalibrationResult, args: argparse.Namespace) -> str:
    """The recommended `force.joint_torques` section, commented, ready to paste under `force:`."""
    lines = [f"# force.joint_torques recommended by `armwarden calibrate-contact` ({result.executed} motions, "
             f"seed {args.seed}, margin {args.margin:g}). Paste it under `force:` in the policy (indented),",
             "# replacing the joint_torques there, then run `armwarden check-policy`.",
             "# Per joint: largest residual seen with nothing touching the arm -> after the fitted friction -> limit.",
             *[f"#   {r.name}: {r.peak_residual_nm:.2f} -> {r.peak_after_friction_nm:.2f} -> {r.limit_nm:g} N·m "
               f"({_margin_text(r)}, {r.samples} samples)" for r in result.recommendations],
             yaml.safe_dump({"joint_torques": result.section}, sort_keys=False, default_flow_style=False).rstrip()]
    return "\n".join(lines) + "\n"


def render_summary(result: CalibrationResult, margin: float) -> str:
    """The per-joint summary for stderr: what was seen, the limit, the false-alarm margin it gives,
    the Guard's own monitor's peak beside it (with the policy's friction allowance, as a cross-check),
    and a warning where the limit could not keep the requested margin (the format's cap)."""
    width = max(len(r.name) for r in result.recommendations)
    lines = [f"calibrate-contact: {result.executed} motions, {len(result.skipped)} skipped, "
             f"{'back home' if result.returned_home else 'NOT back home'}, "
             f"{result.recommendations[0].samples} samples per joint",
             f"  {'joint':<{width}}  residual  after friction  limit [N·m]  false-alarm margin  monitor peak"]
    monitor = result.monitor_peaks_nm or [math.nan] * len(result.recommendations)
    for r, seen in zip(result.recommendations, monitor, strict=True):
        margin_text = "inf" if math.isinf(r.margin) else f"{r.margin:.1f}x"
        note = ""
        if r.limit_nm < margin * r.peak_after_friction_nm:
            note = (f"   WARNING: capped at {MAX_EXTERNAL_TORQUE_NM:g} N·m, below {margin:g}x; look for the "
                    "cause (payload, friction, model) before using it")
        elif r.limit_nm == MIN_LIMIT_NM and margin * r.peak_after_friction_nm < MIN_LIMIT_NM:
            note = f"   (the {MIN_LIMIT_NM:g} N·m floor)"
        lines.append(f"  {r.name:<{width}}  {r.peak_residual_nm:8.2f}  {r.peak_after_friction_nm:14.2f}  "
                     f"{r.limit_nm:11g}  {margin_text:>18}  {seen:12.2f}{note}")
    if result.monitor_peaks_nm and not np.allclose(result.replayed_peaks_nm, result.monitor_peaks_nm, atol=1e-3):
        lines.append("calibrate-contact: WARNING: the recorded samples do not reproduce the Guard monitor's peaks "
                     f"(replayed {np.round(result.replayed_peaks_nm, 2).tolist()}): trust the monitor's column")
    if result.force_limit_n is not None:
        lines.append(f"calibrate-contact: the TCP force estimate peaked at {result.peak_force_n:.1f} N with the fitted "
                     f"friction: max_tcp_force_n {result.force_limit_n:g} N (max_contact_force_n "
                     f"{result.max_contact_force_n:g} N)")
    else:
        force_margin = result.max_contact_force_n / result.peak_force_n if result.peak_force_n > 0 else math.inf
        lines.append(f"calibrate-contact: the TCP force estimate peaked at {result.peak_force_n:.1f} N with the fitted "
                     f"friction (max_contact_force_n {result.max_contact_force_n:g} N: {force_margin:.1f}x); no "
                     "max_tcp_force_n fits under it" + ("" if force_margin >= margin else
                                                          f"; WARNING: under {margin:g}x, the force limit may stop "
                                                          "motions that touch nothing"))
    if len(result.skipped) > result.executed:
        lines.append(f"calibrate-contact: WARNING: {len(result.skipped)} of {result.planned} motions were skipped: the "
                     "limits rest on few motions; look at why, or run more (--motions, another --seed)")
    return "\n".join(lines)


def calibrate_command(args: argparse.Namespace, stdin: TextIO = sys.stdin, stderr: TextIO = sys.stderr) -> int:
    if args.motions < 1 or not (math.isfinite(args.margin) and args.margin >= 1):
        print("armwarden calibrate-contact: --motions must be at least 1 and --margin at least 1", file=stderr)
        return EXIT_REFUSED
    try:
        policy = load_policy(args.policy)
    except ArmWardenError as exc:
        print(f"armwarden calibrate-contact: {exc}", file=stderr)
        return EXIT_REFUSED
    if not _approved(policy, args, stdin, stderr):
        return EXIT_REFUSED
    options = CalibrationOptions(policy=policy, backend=args.backend, backend_config=args.backend_config,
                                 motions=args.motions, seed=args.seed, margin=args.margin,
                                 operator=args.operator or getpass.getuser(), audit_log=args.audit_log)
    try:
        result = anyio.run(lambda: run_calibration(
            options, progress=lambda line: print(f"calibrate-contact: {line}", file=stderr, flush=True)))
    except AuditWriteError as exc:
        print(f"armwarden calibrate-contact: {exc}", file=stderr)
        return EXIT_STOPPED
    except (ArmWardenError, ValueError) as exc:
        print(f"armwarden calibrate-contact: {exc}; nothing moved", file=stderr)
        return EXIT_REFUSED
    if result.stopped is not None:
        print(f"armwarden calibrate-contact: stopped at {result.stopped}; nothing more moved and nothing is "
              f"recommended (audit log: {args.audit_log})", file=stderr)
        return EXIT_STOPPED
    for skipped in result.skipped:
        print(f"calibrate-contact: skipped {skipped}", file=stderr)
    if result.executed == 0 or not result.recommendations:
        print("armwarden calibrate-contact: no motion ran, so nothing is recommended (the skipped motions say why)",
              file=stderr)
        return EXIT_STOPPED
    text = render_section(result, args)
    if args.output is not None:
        args.output.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    print(render_summary(result, args.margin), file=stderr)
    if args.output is not None:
        print(f"calibrate-contact: wrote {args.output}", file=stderr)
    return EXIT_OK
