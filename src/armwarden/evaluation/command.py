"""`armwarden eval`: its arguments and its command (exit 0 all passed, 1 anything failed, 2 invalid input)."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import TextIO

import anyio

from armwarden.consent import confirmed
from armwarden.daemon.options import EXIT_REFUSED
from armwarden.evaluation.arguments import (
    FULL_DEATHS,
    FULL_FUZZ,
    FULL_KILLS,
    FULL_LOAD_S,
    FULL_SAFE,
    QUICK_DEATHS,
    QUICK_FUZZ,
    QUICK_KILLS,
    QUICK_LOAD_S,
    QUICK_SAFE,
)
from armwarden.evaluation.faults import FaultsResult, run_faults
from armwarden.evaluation.fuzz import FuzzOptions, FuzzResult, run_fuzz
from armwarden.evaluation.load import LoadResult, run_load
from armwarden.evaluation.report import report_data, report_json, report_markdown
from armwarden.evaluation.ros_cell import FakeCells, fake_cell_config, isolate_ros_domain
from armwarden.evaluation.runner import EvalOptions, EvalResult, NothingSelected, progress, run_evaluation
from armwarden.evaluation.targets import EvalRefused, checked_can_config, default_backend_config
from armwarden.policy import bundled_policy, load_policy


def _backend_config(args: argparse.Namespace, directory: Path) -> Path | None:
    """The config the daemon gets: for `can` a checked private copy (emulator only, `EvalRefused` otherwise)."""
    given = Path(args.backend_config) if args.backend_config else default_backend_config(args.backend)
    if given is None:
        return None
    if args.backend == "can":
        progress(f"can backend config {given}: checking that it runs the emulator on the virtual bus")
        return checked_can_config(given.resolve(), directory)
    return given.resolve()


#: why the parts that move outside an approved plan do not run on a user's ROS cell
USERS_CELL_WHY = ("not run on a user's ROS cell (--backend ros2 with --backend-config): it {what}, outside any "
                  "approved plan; run it on the fake cell (no --backend-config)")
USERS_CELL_PARTS = {
    "fuzz": ("--fuzz-calls", "sends thousands of generated calls, valid gripper moves among them"),
    "faults": ("--kills", "kills the daemon mid-motion, leaving the cell to finish the goal with no daemon watching"),
    "load": ("--load-seconds", "races 16 clients' approved executes and e-stops against each other"),
}


def users_cell_moves(options: EvalOptions) -> str:
    """What the person at a user's own cell approves before anything moves."""
    robot, motion = options.policy.robot, options.policy.motion
    home = ", ".join(f"{q:+.2f}" for q in robot.home_joint_positions)
    return (f"armwarden eval will move YOUR arm ({robot.name}) on the ROS 2 cell of {options.backend_config}: "
            f"{options.safe_count} random reachable targets within the policy and the few scenario motions that "
            "execute a plan, each planned, checked by the envelope and audited, and approved by the evaluation "
            f"itself, not by a person; at up to the policy's largest scalings ({motion.max_velocity_scaling:g} of "
            f"each joint's velocity, {motion.max_acceleration_scaling:g} of its acceleration). Start with the arm at "
            f"the policy's home ({home} rad), keep the cell clear and the e-stop in reach.")


def eval_command(args: argparse.Namespace, stdin: TextIO = sys.stdin, stderr: TextIO = sys.stderr) -> int:
    policy_path = Path(args.policy) if args.policy else bundled_policy()
    policy = load_policy(policy_path)  # a PolicyError is the command line's exit 2
    with tempfile.TemporaryDirectory(prefix="armwarden-eval-config-") as private:
        cells: FakeCells | None = None
        try:
            if args.backend == "ros2" and args.backend_config is None:
                backend_config = fake_cell_config(Path(private))
                domain = isolate_ros_domain()
                progress(f"ros2: the fake FR3 cell, one process per daemon, on ROS_DOMAIN_ID={domain} with "
                         f"ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; actuation counted as the goals the cell accepted; "
                         f"the daemon's joint-state and wrench ages widened ({backend_config.name})")
                cells = FakeCells(Path(private))
            else:
                backend_config = _backend_config(args, Path(private))
        except (EvalRefused, OSError) as exc:  # never started: it could reach a real arm, or the config is unusable
            progress(str(exc))
            return EXIT_REFUSED
        options = EvalOptions(policy_path=policy_path.resolve(), policy=policy, backend=args.backend,
                              backend_config=backend_config,
                              safe_count=0 if args.only else QUICK_SAFE if args.quick else FULL_SAFE,
                              seed=args.seed, only=tuple(args.only or ()), cells=cells)
        if options.on_users_cell:
            refused = _users_cell_refusal(args)
            if refused is not None:
                progress(refused)
                return EXIT_REFUSED
            if not confirmed(users_cell_moves(options), assume_yes=args.yes, command="armwarden eval", stdin=stdin,
                             stderr=stderr):
                return EXIT_REFUSED
            progress("ros2 with your own cell's config: the unsafe scenarios and the safe requests only (every motion "
                     "a plan the evaluation approves, within the policy); " + "; ".join(
                         f"{part}: {USERS_CELL_WHY.format(what=what)}" for part, (_, what) in USERS_CELL_PARTS.items()))
        try:
            return _run(args, options)
        finally:
            if cells is not None:
                cells.stop()


def _users_cell_refusal(args: argparse.Namespace) -> str | None:
    """Why the options asked for cannot run on a user's ROS cell (fuzz, faults, load), or None."""
    asked = [flag for flag, value in (("--fuzz-only", args.fuzz_only), ("--fuzz-calls", args.fuzz_calls),
                                      ("--kills", args.kills), ("--backend-deaths", args.backend_deaths),
                                      ("--load-seconds", args.load_seconds)) if value]
    if not asked:
        return None
    return (f"refusing {', '.join(asked)} with --backend ros2 and your own --backend-config: fuzzing, faults and "
            "load move the arm outside any approved plan (generated gripper moves, a daemon or the cell killed "
            "mid-motion, racing executes); they run on the fake FR3 cell (no --backend-config)")


def _run(args: argparse.Namespace, options: EvalOptions) -> int:
    # --only is a filtered scenario run: no fuzzing unless asked for
    default_calls = 0 if args.only else QUICK_FUZZ if args.quick else FULL_FUZZ
    fuzz_calls = args.fuzz_calls if args.fuzz_calls is not None else default_calls
    fuzz: FuzzResult | str = "not asked for (--fuzz-calls 0, or --only)"
    default_kills = 0 if args.only or args.fuzz_only else QUICK_KILLS if args.quick else FULL_KILLS
    kills = args.kills if args.kills is not None else default_kills
    default_deaths = 0 if args.only or args.fuzz_only else QUICK_DEATHS if args.quick else FULL_DEATHS
    deaths = args.backend_deaths if args.backend_deaths is not None else default_deaths
    faults: FaultsResult | str = "not asked for (--kills 0 and --backend-deaths 0, --only or --fuzz-only)"
    default_load = 0.0 if args.only or args.fuzz_only else QUICK_LOAD_S if args.quick else FULL_LOAD_S
    load_s = args.load_seconds if args.load_seconds is not None else default_load
    load: LoadResult | str = "not asked for (--load-seconds 0, --only or --fuzz-only)"
    if options.on_users_cell:  # defaults only here: asking for them was refused (`_users_cell_refusal`)
        fuzz_calls = kills = deaths = 0
        load_s = 0.0
        fuzz, faults, load = (USERS_CELL_WHY.format(what=USERS_CELL_PARTS[part][1]) for part in ("fuzz", "faults", "load"))
    if load_s < 0 or args.load_clients < 2:
        progress("--load-seconds must be 0 or more and --load-clients at least 2")
        return 2
    if kills < 0 or deaths < 0:
        progress("--kills and --backend-deaths must be 0 or more")
        return 2
    try:
        result = EvalResult() if args.fuzz_only else anyio.run(run_evaluation, options)
        if fuzz_calls > 0:
            fuzz = _fuzz(options, FuzzOptions(calls=fuzz_calls, seed=args.seed))
        if kills > 0 or deaths > 0:
            with tempfile.TemporaryDirectory(prefix="armwarden-eval-faults-") as directory:
                faults = anyio.run(run_faults, options, Path(directory), kills, True, deaths)
        if load_s > 0:
            load = anyio.run(run_load, options, args.load_clients, load_s)
    except NothingSelected as exc:  # invalid input, like a policy error
        progress(str(exc))
        return 2
    except Exception as exc:  # the daemon refused to start, or the session broke: no result to report
        progress(f"could not complete: {exc!r}")
        return EXIT_REFUSED
    data = report_data(options, result, fuzz, faults, load, scenarios_run=not args.fuzz_only)
    markdown = report_markdown(data)
    if args.report:
        Path(args.report).write_text(markdown, encoding="utf-8")
    else:
        sys.stdout.write(markdown)
    if args.json:
        Path(args.json).write_text(report_json(data), encoding="utf-8")
    failed = sum(not r.passed for r in result.unsafe)
    progress(f"{len(result.unsafe) - failed}/{len(result.unsafe)} unsafe scenarios passed, "
             f"{result.safe.executed}/{result.safe.attempted} safe requests executed")
    return 0 if data["passed"] else 1


def _fuzz(options: EvalOptions, fuzz: FuzzOptions) -> FuzzResult | str:
    """The fuzz run, or why it cannot run: hypothesis is a development dependency, not a runtime one."""
    try:
        import hypothesis  # noqa: F401
    except ImportError:
        return "hypothesis is not installed (pip install 'armwarden[dev]')"
    return anyio.run(run_fuzz, options, fuzz)
