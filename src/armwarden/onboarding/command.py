"""The `armwarden init` subcommand: its flags, and the summary it prints (stdout) as it goes (stderr)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from armwarden.core.errors import PolicyError
from armwarden.onboarding.fitted import FitSettings
from armwarden.onboarding.run import InitOptions, run_init, summary

EXIT_OK = 0
EXIT_REFUSED = 2


def add_init_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("description", type=Path, help="the arm's URDF or MJCF file (run xacro first for a .xacro)")
    parser.add_argument("--output", type=Path, required=True, metavar="POLICY",
                        help="the policy to write; POLICY's stem names the fitted geometry (.fitted.yaml) and the "
                             "picture of the arm at home (.home.png) beside it")
    parser.add_argument("--base-frame", default=None, help="the base frame (default: the description's root link)")
    parser.add_argument("--tcp-frame", default=None,
                        help="the TCP frame (default: the frame at the end of the arm chain, when there is one)")
    parser.add_argument("--joints", default=None, metavar="J1,J2,...",
                        help="the arm's joints in kinematic order (default: the longest chain of revolute joints)")
    parser.add_argument("--mesh-path", action="append", type=Path, default=[], metavar="DIR",
                        help="where package:// and relative mesh files are looked up (repeatable)")
    parser.add_argument("--name", default=None, help="the robot's name in the policy (default: the description's)")
    parser.add_argument("--max-bodies", type=int, default=FitSettings.max_bodies,
                        help="capsules tried per link part (fewer: faster, fatter)")
    parser.add_argument("--fitted", type=Path, default=None, metavar="FILE",
                        help="reuse fitted geometry init made before for this same description (no fitting, no meshes)")
    parser.add_argument("--builtin", default=None, metavar="NAME",
                        help="for a robot folder shipped with ArmWarden (src/armwarden/robots/NAME): the policy names "
                             "its description and fitted geometry builtin:NAME")


def init_command(args: argparse.Namespace) -> int:
    joints = tuple(j.strip() for j in args.joints.split(",") if j.strip()) if args.joints else None
    options = InitOptions(description=args.description, output=args.output, base_frame=args.base_frame,
                          tcp_frame=args.tcp_frame, joints=joints, mesh_paths=tuple(args.mesh_path), name=args.name,
                          fit=FitSettings(max_bodies=args.max_bodies), builtin=args.builtin, fitted=args.fitted)
    try:
        result = run_init(options, progress=lambda line: print(f"init: {line}", file=sys.stderr, flush=True))
    except PolicyError as exc:  # the generated policy failed its own check: a bug or an arm it cannot serve
        print(f"armwarden init: the generated policy does not pass its check ({exc.source}):", file=sys.stderr)
        for yaml_path, message in exc.errors:
            print(f"  {yaml_path}: {message}", file=sys.stderr)
        return EXIT_REFUSED
    for line in summary(result):
        print(line)
    return EXIT_OK


__all__ = ["add_init_arguments", "init_command"]
