"""The `armwarden calibrate-contact` subcommand: what it asks the human, what it prints and writes.

On a terminal it lists what will move and waits for `yes`; `--yes` answers for simulation and
CI; with neither (no terminal) it refuses and nothing moves. The recommended section goes to
`--output` or stdout as YAML, the per-joint summary to stderr. The user's policy file is never
edited: they paste the section after reading it.
"""

from __future__ import annotations

import argparse
import getpass
import math
import sys
from pathlib import Path
from typing import TextIO

import anyio
import yaml

from armwarden.calibration.friction_fit import DEFAULT_MARGIN
from armwarden.calibration.run import CalibrationOptions, CalibrationResult, run_calibration
from armwarden.core.errors import ArmWardenError
from armwarden.policy import Policy, load_policy

EXIT_OK, EXIT_STOPPED, EXIT_REFUSED = 0, 1, 2


def add_calibrate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--policy", type=Path, required=True, help="the policy the arm is served with")
    parser.add_argument("--backend", required=True, help="the backend the arm is driven by (fake, mujoco, can, ros2)")
    parser.add_argument("--backend-config", type=Path, default=None, help="the backend's --backend-config file")
    parser.add_argument("--motions", type=int, default=30, help="how many random safe motions (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the motions' goals (the same seed: the same motions)")
    parser.add_argument("--margin", type=float, default=DEFAULT_MARGIN,
                        help=f"recommended limit = margin × the largest residual seen (default {DEFAULT_MARGIN:g})")
    parser.add_argument("--output", type=Path, default=None, help="write the recommended section here (default: stdout)")
    parser.add_argument("--audit-log", type=Path, default=Path("armwarden-calibration-audit.jsonl"),
                        help="where every motion is recorded")
    parser.add_argument("--operator", default=None, help="who approves the calibration (default: the login name)")
    parser.add_argument("--yes", action="store_true", help="approve without asking (simulation, CI)")


def _what_moves(policy: Policy, args: argparse.Namespace) -> str:
    motion = policy.motion
    return (f"calibrate-contact will move the arm ({policy.robot.name}, backend {args.backend}) through "
            f"{args.motions} random motions within ±0.4 rad of home and back home, at "
            f"{motion.max_velocity_scaling:g} of the joints' velocity and {motion.max_acceleration_scaling:g} of their "
            "acceleration limits, every one checked by the envelope and monitored for contact. Keep the cell clear "
            "and the e-stop in reach.")


def _approved(policy: Policy, args: argparse.Namespace, stdin: TextIO, stderr: TextIO) -> bool:
    print(_what_moves(policy, args), file=stderr)
    if args.yes:
        return True
    if not stdin.isatty():
        print("armwarden calibrate-contact: no terminal to ask on and no --yes: nothing moved", file=stderr)
        return False
    print("Type yes to start: ", end="", file=stderr, flush=True)
    return stdin.readline().strip().lower() == "yes"


def render_section(result: CalibrationResult, args: argparse.Namespace) -> str:
    """The recommended `force.joint_torques` section, commented, ready to paste under `force:`."""
    lines = [f"# force.joint_torques recommended by `armwarden calibrate-contact` ({result.executed} motions, "
             f"seed {args.seed}, margin {args.margin:g}).",
             "# Per joint: largest residual seen with nothing touching the arm -> after the fitted friction -> limit.",
             *[f"#   {r.name}: {r.peak_residual_nm:.2f} -> {r.peak_after_friction_nm:.2f} -> {r.limit_nm:g} N·m "
               f"({'no residual' if math.isinf(r.margin) else f'{r.margin:.1f}x margin'}, {r.samples} samples)"
               for r in result.recommendations],
             yaml.safe_dump({"joint_torques": result.section}, sort_keys=False, default_flow_style=False).rstrip()]
    return "\n".join(lines) + "\n"


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
    except (ArmWardenError, ValueError) as exc:
        print(f"armwarden calibrate-contact: {exc}; nothing more moved", file=stderr)
        return EXIT_REFUSED
    if result.stopped is not None:
        print(f"armwarden calibrate-contact: stopped at {result.stopped}; nothing more moved and nothing is "
              "recommended", file=stderr)
        return EXIT_STOPPED
    if not result.recommendations:
        print("armwarden calibrate-contact: no usable samples were recorded", file=stderr)
        return EXIT_STOPPED
    text = render_section(result, args)
    if args.output is not None:
        args.output.write_text(text, encoding="utf-8")
        print(f"calibrate-contact: wrote {args.output}", file=stderr)
    else:
        sys.stdout.write(text)
    for skipped in result.skipped:
        print(f"calibrate-contact: skipped {skipped}", file=stderr)
    return EXIT_OK


__all__ = ["add_calibrate_arguments", "calibrate_command"]
