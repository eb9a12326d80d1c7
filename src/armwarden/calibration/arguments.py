"""The `armwarden calibrate-contact` command line. Kept apart from the command, which imports the
daemon, the Guard and Pinocchio: every `armwarden` invocation builds this parser, `armwarden
estop` among them, and must not wait a second for what only a calibration needs."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["DEFAULT_MARGIN", "DEFAULT_MOTIONS", "add_calibrate_arguments"]

#: recommended limit = margin × the largest residual left after friction
DEFAULT_MARGIN = 2.0
#: random motions a calibration runs (then home)
DEFAULT_MOTIONS = 30


def add_calibrate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--policy", type=Path, required=True, help="the policy the arm is served with")
    parser.add_argument("--backend", required=True, help="the backend the arm is driven by (fake, mujoco, can, ros2)")
    parser.add_argument("--backend-config", type=Path, default=None, help="the backend's --backend-config file")
    parser.add_argument("--motions", type=int, default=DEFAULT_MOTIONS,
                        help=f"how many random safe motions (default {DEFAULT_MOTIONS})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the motions' goals (the same seed: the same motions)")
    parser.add_argument("--margin", type=float, default=DEFAULT_MARGIN,
                        help=f"recommended limit = margin × the largest residual seen (default {DEFAULT_MARGIN:g})")
    parser.add_argument("--output", type=Path, default=None, help="write the recommended section here (default: stdout)")
    parser.add_argument("--audit-log", type=Path, default=Path("armwarden-audit.jsonl"),
                        help="append-only audit log (JSONL) every motion is recorded in, as serve's")
    parser.add_argument("--operator", default=None, help="who approves the calibration (default: the login name)")
    parser.add_argument("--yes", action="store_true", help="approve without asking (simulation, CI)")
