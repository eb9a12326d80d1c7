#!/usr/bin/env python3
"""Mutation testing of the safety core: delete or invert one check at a time, and see a test fail.

    python scripts/mutation.py                  # every mutant; exit 1 if any survives
    python scripts/mutation.py --list           # the mutants, their edits and their tests
    python scripts/mutation.py --only NAME ...  # just these (repeat --only)
    python scripts/mutation.py --json FILE      # also write the results as JSON

Each mutant below is a one-line edit of `src/armwarden`: a snippet of one line that must occur
exactly once in its file, and what replaces it (`if x:` -> `if False:`, a `raise` -> `pass`). For
each mutant the script copies `src` into a temporary directory, applies the edit to the copy (the
shared tree is never touched), and runs the mutant's own test selection with `PYTHONPATH` pointing
at the copy. A probe plugin records, in the child, where every `armwarden` module was imported
from: a run that imported anything from elsewhere, or never imported the mutated module, is an
error, not a result. Before the mutants, the union of their selections runs once on an unmutated
copy and must pass (a selection that fails anyway proves nothing).

Outcomes: killed (the selection failed), survived (it passed: no test needs that check),
error (the anchor no longer matches exactly once — the code moved on and the mutant must be
updated —, the edit does not compile, the probe saw the wrong code, or pytest could not run).
The kill ratio is killed / all mutants run; errors count against it, so a refactor that leaves an
anchor behind shows up instead of silently shrinking the run.

Only in-process tests belong in a selection: a test that starts the daemon as a child process
runs the shared tree's `src` (tests/helpers.py `child_env`), not the mutated copy.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
PACKAGE = "armwarden"
#: how long one mutant's test run may take before it counts as killed by a timeout [s]
DEFAULT_TIMEOUT_S = 600.0

Outcome = Literal["killed", "survived", "error", "passed"]  # "passed": the baseline only


@dataclass(frozen=True)
class Mutant:
    """One check deleted or inverted: `anchor` (one line's text, exactly once in `path`) becomes
    `replacement`; `tests` (pytest node ids, relative to the repository) must then fail."""

    name: str
    #: the file, relative to src/armwarden
    path: str
    anchor: str
    replacement: str
    tests: tuple[str, ...]
    #: what the check guards, in a few words
    why: str

    @property
    def module(self) -> str:
        """The dotted module name the edit lands in (`armwarden.guard.door`)."""
        return ".".join([PACKAGE, *Path(self.path).with_suffix("").parts])


EXECUTE_LAYERS = "tests/guard/test_execute_layers.py"
REFUSALS = "tests/server/test_refusals.py"
GATE = "tests/server/test_execution_gate.py"
RACES = "tests/server/test_stop_races.py"

MUTANTS: tuple[Mutant, ...] = (
    # ------------------------------------------------------------------ the Guard (guard/door.py)
    Mutant("door-estop-latch-gate", "guard/door.py",
           'self.require_not_estopped("execute_plan")', "pass",
           (f"{EXECUTE_LAYERS}::test_an_estop_after_the_plan_store_handed_the_plan_out_refuses_before_execution_started",),
           "execute_plan refuses once the e-stop latched, before execution_started is written"),
    Mutant("door-last-stop-check", "guard/door.py",
           "if self.stopper.generation != stop_generation or self.latch.is_latched:", "if False:",
           (f"{EXECUTE_LAYERS}::test_a_stop_after_the_last_checks_is_refused_by_the_guard_before_the_hand_over",),
           "a stop or e-stop since the slot was claimed: the Guard refuses before the hand-over"),
    Mutant("door-busy-slot", "guard/door.py",
           'raise refuse(RefusalCode.BUSY, f"plan {self._execution.plan_id} is still executing; the plan {plan_id} stays usable")',
           "pass",
           (f"{REFUSALS}::test_two_concurrent_executions_one_runs_and_the_other_is_refused_busy[legacy]",),
           "one execution at a time"),
    Mutant("door-approval-granted", "guard/door.py",
           'raise approval.refusal(f"execute_plan {plan.plan_id}")', "pass",
           (f"{REFUSALS}::test_execution_is_refused_when_the_human_declines[legacy]",),
           "a plan a human did not approve does not run"),
    Mutant("door-approval-digest", "guard/door.py",
           "if asked_a_human and shown_digest != plan.digest:", "if False:",
           (f"{GATE}::test_an_approval_for_one_plan_never_runs_another_under_the_same_id",),
           "the approval was given for the plan that runs"),
    Mutant("door-envelope-recheck", "guard/door.py",
           "if recheck.hard:", "if False:",
           (f"{GATE}::test_a_plan_that_breaks_the_envelope_in_force_at_execution_is_refused[legacy]",),
           "re-validation against the envelope right before moving"),
    Mutant("door-stale-start", "guard/door.py",
           "raise refuse(stale.code, stale.message)", "pass",
           (f"{GATE}::test_an_arm_moved_by_another_client_while_the_human_decided_is_refused_stale",),
           "the arm is still where the plan starts"),
    # ------------------------------------------------------------------ the flows
    Mutant("runner-require-wrench", "guard/execution.py",
           "raise SafetyRefusal(RefusalCode.NO_WRENCH, no_contact_message(self.policy, self.backend))", "pass",
           (f"{EXECUTE_LAYERS}::test_a_wrench_that_disappears_while_a_human_decides_refuses_at_the_start",),
           "no wrench at run time: refused when the policy requires one"),
    Mutant("runner-in-contact", "guard/execution.py",
           "if monitor.baseline_excessive:", "if False:",
           (f"{EXECUTE_LAYERS}::test_an_arm_already_pressing_with_more_than_twice_the_force_limit_is_refused_in_contact",),
           "no motion from a contact over twice the force limit"),
    Mutant("planning-estop-while-planning", "guard/planning.py",
           "if state.latch.generation != generation:", "if False:",
           (f"{RACES}::test_a_plan_made_across_a_channel_estop_is_discarded",
            f"{REFUSALS}::test_a_plan_being_made_when_the_estop_latches_is_discarded_and_cannot_run_after_the_reset[legacy]"),
           "a plan made across an e-stop is discarded"),
    Mutant("gripper-estop-latch-gate", "guard/gripper.py",
           "state.require_not_estopped(tool)", "pass",
           (f"{REFUSALS}::test_motion_gripper_and_control_tools_are_refused_while_estopped[gripper_move-legacy]",),
           "no gripper action while the e-stop is latched"),
    Mutant("actions-approval-digest", "guard/actions.py",
           'if approval.via == "elicitation" and shown != action.prompt().digest:', "if False:",
           (f"{REFUSALS}::test_an_action_question_left_open_across_an_estop_and_its_reset_does_not_actuate",),
           "a control action's approval was given for this very request"),
    # ------------------------------------------------------------------ the plan store
    Mutant("plans-ttl", "approval/plans.py",
           "if self._clock() >= plan.expires_mono:", "if False:",
           ("tests/safety/test_plans.py",),
           "plans expire"),
    Mutant("plans-estop-generation", "approval/plans.py",
           "if estop_generation is not None and plan.estop_generation != estop_generation:", "if False:",
           ("tests/safety/test_plans.py",
            f"{REFUSALS}::test_a_stored_plan_from_before_an_estop_is_refused_after_the_reset_even_if_it_escaped_invalidation"),
           "nothing planned before an e-stop runs after it"),
    Mutant("plans-owner", "approval/plans.py",
           "if plan.owner is not None and caller != plan.owner:", "if False:",
           ("tests/safety/test_plans.py",),
           "only the client that planned a motion may run it"),
    Mutant("plans-single-use", "approval/plans.py",
           "del self._plans[found.plan_id]", "pass",
           ("tests/safety/test_plans.py",),
           "a plan runs at most once"),
    # ------------------------------------------------------------------ the envelope
    Mutant("envelope-cartesian-length", "safety/envelope.py",
           "if tcp_length > self.limits.max_cartesian_step_m:", "if False:",
           (f"{REFUSALS}::test_cartesian_path_over_the_length_cap_is_refused[legacy]",),
           "the TCP path length cap"),
    Mutant("envelope-keep-out", "safety/kernel/sample.py",  # the compiled check the envelope runs
           "hit = distance <= radius", "hit = False",
           (f"{REFUSALS}::test_elbow_sweeping_through_a_keep_out_zone_is_refused_although_the_tcp_stays_clear[legacy]",),
           "links stay out of keep-out zones"),
    Mutant("envelope-velocity", "safety/waypoints.py",
           "if vel_ratio > lim.max_velocity_scaling * _VELOCITY_TOLERANCE:", "if False:",
           ("tests/safety/test_envelope.py::test_waypoint_timing_faster_than_the_velocity_cap_is_refused",),
           "waypoint timing within the velocity cap"),
    # ------------------------------------------------------------------ approvals
    Mutant("approval-reset-always", "approval/decision.py",
           "return True  # releasing an e-stop always needs a human", "pass",
           ("tests/safety/test_approval_required.py",),
           "reset_estop needs a human under every approval mode"),
    Mutant("approval-form-tick", "approval/decision.py",
           "if data.approve is True:", "if True:",
           (f"{REFUSALS}::test_execution_is_refused_when_the_human_accepts_without_ticking_approve[legacy]",),
           "only a ticked 'approve' approves"),
    Mutant("approval-no-elicitation-reset", "approval/decision.py",
           'if policy.approval.on_client_without_elicitation == "allow" and action != "reset_estop":',
           'if policy.approval.on_client_without_elicitation == "allow":',
           (f"{REFUSALS}::test_reset_estop_always_needs_a_human_even_when_the_policy_allows_clients_without_elicitation[legacy]",),
           "a client that cannot ask a human never releases an e-stop"),
    # ------------------------------------------------------------------ the rate limiter
    Mutant("ratelimit-global-bucket", "safety/ratelimit.py",
           "if bucket.has_token() and self._global.has_token():", "if bucket.has_token():",
           ("tests/safety/test_ratelimit.py",),
           "the global bucket limits all tools together"),
    # ------------------------------------------------------------------ force
    Mutant("force-limit", "safety/force.py",
           "if force_n > force_max:", "if False:",
           ("tests/safety/test_force.py",),
           "contact force over the limit stops the motion"),
    Mutant("force-frozen-wrench", "safety/force.py",
           "elif now - self._stamp_advanced_mono > timeout_s:", "elif False:",
           ("tests/safety/test_force.py",),
           "a wrench whose stamp stops advancing fails closed"),
    Mutant("force-joint-torque-limit", "safety/force.py",
           "over = [j for j, threshold in enumerate(thresholds) if abs(torques[j]) > threshold]", "over = []",
           ("tests/safety/test_joint_torque_monitor.py",),
           "an external joint torque over its limit stops the motion"),
    Mutant("contact-nan-torques", "safety/contact_source.py",
           "if not all(np.all(np.isfinite(x)) for x in (q, v, tau)) or not np.isfinite(state.stamp):", "if False:",
           ("tests/safety/test_joint_torque_monitor.py",),
           "NaN joint torques are an unusable reading, never fed to the observer"),
    # ------------------------------------------------------------------ policy bounds
    Mutant("checks-grasp-force", "safety/checks.py",
           "if force_n is not None and not (0.0 < force_n <= cfg.max_grasp_force_n):", "if False:",
           ("tests/guard/test_own_checks.py::test_a_grasp_force_above_the_policy_cap_is_refused_by_the_guard_itself",),
           "grasp force within the policy's max_grasp_force_n"),
    Mutant("checks-collision-thresholds", "safety/checks.py",
           "if not (0.0 < force_n <= force.max_contact_force_n):", "if False:",
           ("tests/guard/test_own_checks.py::test_collision_thresholds_above_the_policy_cap_are_refused_by_the_guard_itself",),
           "collision thresholds never raised above the policy's contact force"),
    Mutant("policy-monitor-period", "policy/motion.py",
           "if period_s > self.wrench_timeout_s:", "if False:",
           ("tests/test_policy.py::test_force_monitor_polling_slower_than_the_wrench_timeout_is_refused",),
           "a force monitor polling slower than the wrench timeout is an invalid policy"),
    # ------------------------------------------------------------------ the backend base class
    Mutant("base-stop-landed", "backends/base.py",
           "if self._stop_landed():", "if False:",
           ("tests/backends/test_base_execute_gate.py",),
           "execute: a trajectory decided before a stop does not start"),
    Mutant("base-start-tolerance", "backends/base.py",
           "if not deviation[worst] <= self.start_tolerance_rad:", "if False:",
           ("tests/backends/test_minimal_backend.py::TestMinimalBackendContract"
            "::test_a_trajectory_that_does_not_start_at_the_arm_is_refused_and_nothing_moves",),
           "execute: a trajectory must start where the arm is"),
    # ------------------------------------------------------------------ access rules
    Mutant("access-observer-tools", "transport/access.py",
           "return spec is not None and spec.observer_may_call", "return True",
           ("tests/transport/test_http.py::test_observer_may_not_call_other_tools",),
           "an observer token calls only introspection, perception and stop tools"),
)

PROBE_MODULE = "armwarden_mutation_probe"
PROBE_ENV = "ARMWARDEN_MUTATION_PROBE"
PROBE_SOURCE = f'''"""Loaded into a mutation run's pytest (-p {PROBE_MODULE}): where armwarden came from."""
import json
import os
import sys


def pytest_sessionfinish(session, exitstatus):
    modules = {{name: getattr(module, "__file__", None) for name, module in list(sys.modules.items())
               if name == "{PACKAGE}" or name.startswith("{PACKAGE}.")}}
    with open(os.environ["{PROBE_ENV}"], "w", encoding="utf-8") as out:
        json.dump(modules, out)
'''


@dataclass(frozen=True)
class Result:
    """One mutant's (or the baseline's) run."""

    name: str
    path: str
    outcome: Outcome
    seconds: float
    detail: str
    tests: tuple[str, ...]


# ---------------------------------------------------------------------- the edit
def mutated_source(mutant: Mutant, source: str) -> str:
    """`source` with the mutant's edit applied. Raises ValueError when the anchor does not occur
    exactly once, when anchor or replacement spans lines, or when the edit changes nothing."""
    if "\n" in mutant.anchor or "\n" in mutant.replacement:
        raise ValueError(f"{mutant.name}: a mutant is a one-line edit; anchor and replacement must not contain a newline")
    if mutant.anchor == mutant.replacement:
        raise ValueError(f"{mutant.name}: the replacement equals the anchor")
    count = source.count(mutant.anchor)
    if count != 1:
        raise ValueError(f"{mutant.name}: anchor found {count} times in src/{PACKAGE}/{mutant.path} "
                         f"(must be exactly once): {mutant.anchor!r}")
    return source.replace(mutant.anchor, mutant.replacement)


def apply(mutant: Mutant, src_root: Path) -> None:
    """Edit the copy of src at `src_root` in place; the result must still compile."""
    target = src_root / PACKAGE / mutant.path
    if not target.is_file():
        raise ValueError(f"{mutant.name}: no file src/{PACKAGE}/{mutant.path}")
    text = mutated_source(mutant, target.read_text(encoding="utf-8"))
    try:
        compile(text, str(target), "exec")
    except SyntaxError as exc:
        raise ValueError(f"{mutant.name}: the edited file does not compile: {exc}") from exc
    target.write_text(text, encoding="utf-8")


# ---------------------------------------------------------------------- one run
def copy_src(workdir: Path) -> Path:
    """A fresh copy of the shared tree's src under `workdir`; returns the copy's src directory."""
    copy = workdir / "src"
    shutil.copytree(SRC, copy, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    return copy


def run_selection(name: str, tests: Sequence[str], src_copy: Path, probe_dir: Path, timeout_s: float,
                  expect_module: str | None) -> tuple[int | None, str, str]:
    """Run pytest on `tests` against `src_copy`. Returns (exit code or None on timeout, problem,
    failure): `problem` is empty unless pytest could not run or the probe saw code from outside
    the copy (or not the mutated module); `failure` is pytest's line naming the failed test."""
    probe_file = probe_dir / f"{name}.json"
    probe_file.unlink(missing_ok=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(src_copy), str(probe_dir)]), PROBE_ENV: str(probe_file),
           "COLUMNS": "400"}  # wide enough for pytest to say why the test failed
    command = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-p", PROBE_MODULE, *tests]
    try:
        done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        return None, "", ""
    lines = (done.stdout + done.stderr).strip().splitlines()
    tail = "\n".join(lines[-15:])
    failure = next((line for line in lines if line.startswith(("FAILED ", "ERROR "))), "")
    if not probe_file.is_file():
        return done.returncode, f"the probe wrote nothing (pytest exit {done.returncode}):\n{tail}", failure
    modules: dict[str, str | None] = json.loads(probe_file.read_text(encoding="utf-8"))
    copy_root = src_copy.resolve()
    outside = sorted(name for name, file in modules.items()
                     if file is not None and not Path(file).resolve().is_relative_to(copy_root))
    if not modules or outside:
        return done.returncode, f"armwarden was imported from outside the copy ({', '.join(outside[:3]) or 'not at all'})", failure
    if expect_module is not None and expect_module not in modules:
        return done.returncode, f"the selected tests never imported {expect_module}", failure
    return done.returncode, "" if done.returncode in (0, 1) else f"pytest exit {done.returncode}:\n{tail}", failure


def run_mutant(mutant: Mutant, timeout_s: float) -> Result:
    started = time.monotonic()

    def result(outcome: Outcome, detail: str) -> Result:
        return Result(mutant.name, mutant.path, outcome, round(time.monotonic() - started, 1), detail, mutant.tests)

    with tempfile.TemporaryDirectory(prefix="armwarden-mutant-") as work:
        workdir = Path(work)
        src_copy = copy_src(workdir)
        probe_dir = write_probe(workdir)
        try:
            apply(mutant, src_copy)
        except ValueError as exc:
            return result("error", str(exc))
        code, problem, failure = run_selection(mutant.name, mutant.tests, src_copy, probe_dir, timeout_s, mutant.module)
    if code is None:
        return result("killed", f"the tests did not finish within {timeout_s:g} s (a hang counts as caught)")
    if problem:
        return result("error", problem)
    if code == 1:
        return result("killed", failure or "a test failed")
    return result("survived", "every selected test passed without this check")


def run_baseline(mutants: Sequence[Mutant], timeout_s: float) -> Result:
    """The union of the selections on an unmutated copy: it must pass."""
    tests = tuple(dict.fromkeys(test for mutant in mutants for test in mutant.tests))
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="armwarden-mutant-") as work:
        workdir = Path(work)
        src_copy = copy_src(workdir)
        probe_dir = write_probe(workdir)
        code, problem, _ = run_selection("baseline", tests, src_copy, probe_dir, timeout_s, None)
    seconds = round(time.monotonic() - started, 1)
    if code == 0 and not problem:
        return Result("baseline", "", "passed", seconds, "every selected test passes on the unmutated source", tests)
    why = problem or ("timed out" if code is None else f"pytest exit {code}")
    return Result("baseline", "", "error", seconds, f"the selections fail without any mutation: {why}", tests)


def write_probe(workdir: Path) -> Path:
    probe_dir = workdir / "probe"
    probe_dir.mkdir()
    (probe_dir / f"{PROBE_MODULE}.py").write_text(PROBE_SOURCE, encoding="utf-8")
    return probe_dir


# ---------------------------------------------------------------------- the command
def select(names: Iterable[str] | None) -> list[Mutant]:
    """The mutants named (all when None); SystemExit(2) for an unknown name."""
    if not names:
        return list(MUTANTS)
    by_name = {mutant.name: mutant for mutant in MUTANTS}
    unknown = [name for name in names if name not in by_name]
    if unknown:
        print(f"unknown mutant(s) {unknown}; see --list", file=sys.stderr)
        raise SystemExit(2)
    return [by_name[name] for name in dict.fromkeys(names)]


def list_mutants(mutants: Sequence[Mutant]) -> None:
    for mutant in mutants:
        print(f"{mutant.name}  (src/{PACKAGE}/{mutant.path}): {mutant.why}")
        print(f"    {mutant.anchor}")
        print(f"    -> {mutant.replacement}")
        for test in mutant.tests:
            print(f"    test: {test}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--list", action="store_true", help="print the mutants and exit")
    parser.add_argument("--only", action="append", metavar="NAME", help="run only this mutant (repeatable)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the results to FILE as JSON")
    parser.add_argument("--timeout-s", type=float, default=DEFAULT_TIMEOUT_S,
                        help=f"per mutant [s] (default {DEFAULT_TIMEOUT_S:g}); a run past it counts as killed")
    parser.add_argument("--no-baseline", action="store_true",
                        help="skip the run of the unmutated selections (they must pass for a kill to mean anything)")
    args = parser.parse_args(argv)
    mutants = select(args.only)
    if args.list:
        list_mutants(mutants)
        return 0

    command = "python scripts/mutation.py" + "".join(f" --only {m.name}" for m in mutants if args.only)
    print(f"mutation run of the safety core: {len(mutants)} mutant(s)", flush=True)
    baseline = None if args.no_baseline else run_baseline(mutants, args.timeout_s)
    results: list[Result] = []
    if baseline is not None:
        print(f"  baseline  {baseline.seconds:6.1f} s  {baseline.detail}", flush=True)
    if baseline is None or baseline.outcome == "passed":
        for mutant in mutants:
            result = run_mutant(mutant, args.timeout_s)
            results.append(result)
            line = f"  {result.outcome.upper():9} {result.seconds:6.1f} s  {mutant.name}  (src/{PACKAGE}/{mutant.path})"
            if result.outcome != "killed":
                line += f"\n            {result.detail}"
            print(line, flush=True)

    killed = sum(r.outcome == "killed" for r in results)
    survived = sum(r.outcome == "survived" for r in results)
    errors = sum(r.outcome == "error" for r in results)
    ratio = killed / len(results) if results else 0.0
    print(f"{killed} killed, {survived} survived, {errors} errors of {len(results)} mutants: kill ratio {ratio:.1%}")
    if args.json is not None:
        report = {
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": command,
            "commit": _git("rev-parse", "HEAD"),
            # the copy is of the working tree: uncommitted edits of src are part of what was mutated
            "src_uncommitted_changes": bool(_git("status", "--porcelain", "--", "src")),
            "baseline": None if baseline is None else asdict(baseline),
            "mutants": [asdict(r) for r in results],
            "killed": killed, "survived": survived, "errors": errors, "total": len(results),
            "kill_ratio": ratio,
        }
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    ok = bool(results) and killed == len(results) and (baseline is None or baseline.outcome == "passed")
    return 0 if ok else 1


def _git(*arguments: str) -> str | None:
    """What `git ARGUMENTS` prints in the repository, stripped; None without git."""
    try:
        done = subprocess.run(["git", *arguments], cwd=REPO, capture_output=True, text=True, check=False)
    except OSError:
        return None
    return done.stdout.strip() or None


if __name__ == "__main__":
    sys.exit(main())
