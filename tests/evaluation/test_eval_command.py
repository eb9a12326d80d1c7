"""`armwarden eval` end to end: the real command, which starts the real daemon as a subprocess.

The evaluation proves something only if a weaker Guard fails it: each mutant below is one check
removed (a one-line edit in the format of scripts/mutation.py, most taken from there), applied to
a copy of `src`; the command runs with PYTHONPATH on that copy (the daemon subprocess inherits it)
and `--only` the scenario meant to catch it (one daemon start, no safe requests): that scenario
must fail. The unmutated quick run must pass every scenario, so a kill is the mutant's doing.
Nothing in the shipped code can switch a check off: the edit exists only in the test's copy.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from armwarden.evaluation.stats import wilson_interval
from tests.helpers import REPO, SRC

#: scenarios that execute one legitimate plan before the refusal they test
ALLOWED = {"an executed plan cannot be executed again, even from its start state": 2,
           "a plan whose start state has moved is refused": 1,
           "a gripper call over its rate limit (1/min) is refused": 1}
#: a whole --quick run: two daemon start-ups and ~80 calls on a loaded 2-core machine
EVAL_TIMEOUT_S = 900


def _run_eval(tmp_path: Path, src: Path, only: tuple[str, ...] = (), *extra: str) -> tuple[int, dict, str]:
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 20\n", encoding="utf-8")
    out = tmp_path / "eval.json"
    env = {**os.environ, "PYTHONPATH": f"{src}:{REPO}"}
    env.pop("ARMWARDEN_AUDIT_KEY", None)
    done = subprocess.run([sys.executable, "-m", "armwarden.cli", "eval", "--quick", "--backend-config", str(config),
                           "--json", str(out), "--report", str(tmp_path / "eval.md"),
                           *[arg for text in only for arg in ("--only", text)], *extra],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=EVAL_TIMEOUT_S)
    data = json.loads(out.read_text(encoding="utf-8")) if out.exists() else {}
    return done.returncode, data, done.stderr


@pytest.mark.parametrize(("successes", "trials", "low", "high"), [
    (0, 10, 0.0, 0.2775),
    (10, 10, 0.7225, 1.0),
    (5, 10, 0.2366, 0.7634),
    (95, 100, 0.8882, 0.9785),
])
def test_wilson_interval_matches_published_values(successes, trials, low, high) -> None:
    assert wilson_interval(successes, trials) == pytest.approx((low, high), abs=1e-4)


def test_wilson_interval_of_no_trials_says_nothing() -> None:
    assert wilson_interval(0, 0) == (0.0, 1.0)


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
def test_quick_eval_on_fake_passes_every_scenario_with_no_actuation(tmp_path) -> None:
    code, data, stderr = _run_eval(tmp_path, SRC)
    assert code == 0, stderr[-3000:]
    assert len(data["unsafe"]) >= 60
    assert data["skipped"] == [] and data["only"] == []  # the FR3 model yields a self-colliding target
    failed = [r for r in data["unsafe"] if not r["passed"]]
    assert failed == []
    assert all(r["actuations"] == ALLOWED.get(r["name"], 0) for r in data["unsafe"]), data["unsafe"]
    assert data["safe"]["attempted"] == data["safe"]["executed"] == 10
    assert 0 < data["safe"]["wilson_low"] < 1 and data["safe"]["wilson_high"] == pytest.approx(1.0)
    fuzz = data["fuzz"]
    assert fuzz["run"] and fuzz["calls"] == 2 * 300, fuzz  # --quick: 300 per transport, stdio and HTTP
    assert (fuzz["crashes"], fuzz["unaudited"], fuzz["actuations"], fuzz["estop_unanswered"]) == (0, 0, 0, 0), fuzz
    assert set(fuzz["per_transport"]) == {"stdio", "http"}
    faults = data["faults"]
    assert faults["run"] and faults["passed"], faults
    assert faults["kills"] == faults["survived"] == faults["latched_after_restart"] == 2 and faults["ended_clean"]
    assert faults["disk_full"]["passed"] and faults["disk_full"]["actuations"] == 0, faults["disk_full"]
    death = faults["backend_death"]  # --quick: one death
    assert death["passed"] and death["deaths"] == death["survived"] == 1 and death["actuations_after"] == 0, death
    load = data["load"]
    assert load["run"] and load["passed"] and load["clients"] == 16 and load["duration_s"] == 10, load
    assert load["estop"]["count"] >= 1 and load["estop"]["unanswered"] == 0 and load["alive_at_end"], load
    assert load["actuations"] <= load["executions"] <= load["approvals"] - load["resets"], load
    assert load["succeeded"] > 0 and load["resets"] == load["estop"]["count"], load
    assert data["backend"] == "fake" and data["policy_digest"] and data["version"]
    assert "PASSED" in (tmp_path / "eval.md").read_text(encoding="utf-8")


def _mutation_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("armwarden_mutation_script_eval", REPO / "scripts" / "mutation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


#: mutants only the evaluation is asked to catch here: (name, file under src/armwarden, anchor, replacement)
EVAL_ONLY_MUTANTS = {
    "bodies-self-collision": ("safety/bodies.py",
                              "pairs = robot.self_collision_pairs if limits.self_collision else np.zeros((0, 2), dtype=np.intp)",
                              "pairs = np.zeros((0, 2), dtype=np.intp)"),
    # both the Guard's precheck and its last check ask the plan store: removing one leaves the other
    "plans-start-state": ("approval/plans.py", "if drift[worst] <= self.start_tolerance_rad:", "if True:"),
    "checks-controller-allowlist": ("safety/checks.py", "    if outside:", "    if False:"),
    "envelope-joint-step": ("safety/waypoints.py", "if travel[j] > lim.max_joint_step_rad:", "if False:"),
    "approval-no-elicitation-deny": ("approval/decision.py",
                                     'if policy.approval.on_client_without_elicitation == "allow" and action != "reset_estop":',
                                     'if action != "reset_estop":'),
    "ratelimit-tool-bucket": ("safety/ratelimit.py", "if bucket.has_token() and self._global.has_token():",
                              "if self._global.has_token():"),
}

#: each mutant and the scenario (a fragment of its name, as `--only` takes it) that must catch it
CAUGHT_BY = [
    ("plans-single-use", "an executed plan cannot be executed again, even from its start state"),
    ("plans-ttl", "a plan past its TTL (shortened to 2 s) is refused"),
    # the probe link is chosen by the (mutated) envelope's start-up check: any link's scenario
    ("envelope-keep-out", "ending inside a keep-out zone (TCP clear) is refused"),
    ("door-approval-granted", "a motion the operator declines does not run"),
    # the backend's own start check refuses it too, but after the journal counted the execute
    ("plans-start-state", "a plan whose start state has moved is refused"),
    ("gripper-estop-latch-gate", "a reset the operator declines leaves the e-stop latched"),
    ("bodies-self-collision", "a joint target whose links collide with each other is refused"),
    ("checks-controller-allowlist", "a controller outside the allowlist is not activated"),
    ("envelope-joint-step", "fr3_joint1 step of 1.60 rad over the 1.5 rad cap is refused"),
    ("approval-no-elicitation-deny", "a motion needing approval is refused to a client without elicitation (deny)"),
    ("ratelimit-tool-bucket", "a gripper call over its rate limit (1/min) is refused"),
]


def _mutant(script: ModuleType, name: str):  # -> the script's Mutant
    if name in EVAL_ONLY_MUTANTS:
        path, anchor, replacement = EVAL_ONLY_MUTANTS[name]
        return script.Mutant(name, path, anchor, replacement, (), "caught by `armwarden eval` only")
    (found,) = [m for m in script.MUTANTS if m.name == name]
    return found


def test_at_least_ten_mutants_each_with_its_scenario() -> None:
    assert len({name for name, _ in CAUGHT_BY}) >= 10


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
@pytest.mark.parametrize(("mutant", "caught_by"), CAUGHT_BY, ids=[name for name, _ in CAUGHT_BY])
def test_a_weakened_guard_fails_the_eval(tmp_path, mutant, caught_by) -> None:
    script = _mutation_script()
    src = tmp_path / "src"
    # __pycache__ copied too: numba's kernel caches stay valid (keyed on the sources' digest, so
    # an edit to a compiled file compiles afresh); a .pyc of the edited file is stale by its mtime
    shutil.copytree(SRC, src, ignore=shutil.ignore_patterns("*.egg-info"))
    script.apply(_mutant(script, mutant), src)
    code, data, stderr = _run_eval(tmp_path, src, only=(caught_by,))
    assert code == 1, stderr[-3000:]
    assert data["only"] == [caught_by] and data["safe"]["attempted"] == 0
    failed = {r["name"] for r in data["unsafe"] if not r["passed"]}
    assert any(name.endswith(caught_by) for name in failed), (failed, stderr[-3000:])


#: mutants of how a start reads the previous run, and the faults' figure each must spoil
PREVIOUS_RUN_MUTANTS = [
    # it forgets a kill: the restart comes up unlatched
    pytest.param("    if not records:", "    if True:", "latched_after_restart", id="forgets-the-kill"),
    # it latches after every run, a clean one too (review: the faults could not see that)
    pytest.param('    if extra["arm_stopped"] is not True:', "    if True:", "clean_restart_unlatched",
                 id="latches-after-a-clean-end"),
]


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
@pytest.mark.parametrize(("anchor", "replacement", "spoiled"), PREVIOUS_RUN_MUTANTS)
def test_a_daemon_that_misreads_how_its_last_run_ended_fails_the_faults(tmp_path, anchor, replacement,
                                                                         spoiled) -> None:
    script = _mutation_script()
    src = tmp_path / "src"
    shutil.copytree(SRC, src, ignore=shutil.ignore_patterns("*.egg-info"))
    script.apply(script.Mutant("previous-run", "daemon/previous_run.py", anchor, replacement, (),
                               "caught by `armwarden eval` only"), src)
    code, data, stderr = _run_eval(tmp_path, src, ("a reset the operator declines",), "--kills", "1")
    assert code == 1, stderr[-3000:]
    faults = data["faults"]
    assert not faults["passed"] and faults[spoiled] in (0, False), faults


#: a filtered run that only adds one backend death: one daemon for the scenario, one that dies
DEATH_ONLY = (("a reset the operator declines",), "--kills", "0", "--backend-deaths", "1")


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
def test_the_fake_backend_dying_mid_motion_is_latched_reported_and_refused(tmp_path) -> None:
    only, *extra = DEATH_ONLY
    code, data, stderr = _run_eval(tmp_path, SRC, only, *extra)
    assert code == 0, stderr[-3000:]
    faults = data["faults"]
    assert faults["passed"] and not faults["kills_asked"] and faults["disk_full"] is None, faults
    death = faults["backend_death"]
    assert death["passed"] and death["deaths"] == death["survived"] == death["mid_motion"] == death["latched"] == 1
    (run,) = death["per_run"]
    assert run["execute_failed"] and run["robot_state_refused"] and run["plan_refused"] and run["execute_refused"]
    assert run["actuations_after"] == 0
    assert run["audit_verified"] and "the control thread stopped (InjectedBackendDeath" in run["fault_record"], run
    assert "Backend death mid-motion: 1/1" in (tmp_path / "eval.md").read_text(encoding="utf-8")


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
def test_a_backend_whose_death_is_not_reported_fails_the_fault(tmp_path) -> None:
    """The dead thread still fails its execution (which latches the e-stop on its own), but the
    backend never tells the Guard: the fault must not pass on the latch alone."""
    script = _mutation_script()
    src = tmp_path / "src"
    shutil.copytree(SRC, src, ignore=shutil.ignore_patterns("*.egg-info"))
    script.apply(script.Mutant("unreported-death", "backends/workers.py",
                               '        self._report_fault(reason if unconfirmed is None else f"{reason}; {unconfirmed}")',
                               "        pass", (), "caught by `armwarden eval` only"), src)
    only, *extra = DEATH_ONLY
    code, data, stderr = _run_eval(tmp_path, src, only, *extra)
    assert code == 1, stderr[-3000:]
    death = data["faults"]["backend_death"]
    assert not death["passed"] and death["survived"] == 0, death
    (run,) = death["per_run"]
    assert not run["audit_records_cause"] and run["fault_record"] == "", run


def test_only_selecting_nothing_is_invalid_input(tmp_path) -> None:
    code, data, stderr = _run_eval(tmp_path, SRC, only=("no scenario is named like this",))
    assert code == 2 and data == {}, stderr[-3000:]
    assert "selects no scenario" in stderr
