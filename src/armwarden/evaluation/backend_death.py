"""Fault injection: the backend dies mid-motion (issue 30, faults: "latched, reported, refused").

Each run starts the daemon with `--eval-backend-death` (evaluation only, refused by the daemon for
any backend that may drive a real arm; `armwarden.daemon.death`), plans a safe move as slowly as a
plan may and a second one, executes the first and, once its progress passes a random fraction of
it, sends SIGUSR2: the backend dies through its real failure path — fake: its control thread,
MuJoCo: its physics thread, CAN: the emulator stops and every actuator goes silent, which the
backend's own RX timeout finds. On ROS 2 the fake cell's process is SIGKILLed instead, as a cell
dies when its driver or host crashes (no topic, no feedback, no result ever again): the daemon has
no flag for it and must notice on its own.

Then, through the SDK client and the files the daemon leaves: the execute must have ended with an
error or abort, not success; `get_safety_status` must report the e-stop latched, saying why, and
`get_robot_state` must refuse (naming the dead thread, or the state too old) rather than serve a
state as if nothing happened; a new plan and the execute of the plan made before the death must
be refused; no actuation may reach the backend after the death (the journal); the audit log must
verify and hold the injection and, after it, the fault the backend itself reported (the record the
Guard writes as it latches on that report: a backend that dies unreported fails here even though
the failed execute latches the e-stop on its own).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import anyio
import numpy as np

from armwarden.audit import verify_file
from armwarden.audit.chain import hmac_key_from_env
from armwarden.audit.verify import decode_records
from armwarden.daemon.death import DEATH_EVENT, DEATH_SIGNAL
from armwarden.evaluation.fault_daemon import (
    FAULT_AT_PROGRESS,
    FAULT_STEP_TIMEOUT_S,
    bounded_call,
    daemon_params,
    fault_client,
    last_startup,
    last_words,
    strike_mid_motion,
)
from armwarden.evaluation.journal import JournalReader, actuations
from armwarden.evaluation.runner import (
    EVAL_WRENCH_TIMEOUT_S,
    UNLIMITED,
    DaemonSession,
    EvalOptions,
    progress,
    safe_goal,
    serve_arguments,
    wait_for_state,
    write_policy,
)
from armwarden.planning.planners import MIN_SCALING

#: the `serve` flag of the injected death (its signal and audit event: `armwarden.daemon.death`)
DEATH_FLAG = "--eval-backend-death"
#: the dying motion's scaling: the slowest a plan may ask for (`planning.planners.MIN_SCALING`),
#: so that a sped-up simulation (the tests' fake runs 20× real time; progress is reported every
#: 0.1 s) is still moving when the death lands (found by the first full run: at the kills' 5 %
#: the fake finished 3 of 5 motions before its control thread died)
DYING = {"velocity_scaling": MIN_SCALING, "acceleration_scaling": MIN_SCALING}
#: the e-stop source of a fault the backend reported on its own (`Stopper.backend_fault`)
BACKEND_FAULT = "backend_fault"
#: how long the backend may take to find its death and the e-stop to latch [s] (CAN: its RX
#: timeout, widened to 1 s for the evaluation, then a servo tick)
LATCH_TIMEOUT_S = 30.0
#: how often the latch is looked at meanwhile [s]
LATCH_POLL_S = 0.1


@dataclass(frozen=True)
class DeathInjection:
    """How a backend is made to die from outside the daemon: what it is (for the report), the
    `serve` flags that allow it, how it is done given the daemon's pid, and the audit event the
    daemon records it with (the backend's report must follow that record; None: the daemon does
    not know, e.g. a ROS 2 cell process killed, and the report must follow the execution's start)."""

    what: str
    serve_flags: tuple[str, ...]
    #: given the daemon's pid and the evaluation's options (the fake ROS cells among them)
    inject: Callable[[int, EvalOptions], None]
    audit_event: str | None
    #: the journal suffix of what reached the backend: the daemon's own (`-journal.jsonl`), or on
    #: the fake ROS cell the daemon's wrapper (`-daemon-journal.jsonl`: the dead cell journals nothing)
    journal_suffix: str = "-journal.jsonl"


def _signal_death(pid: int, options: EvalOptions) -> None:
    os.kill(pid, DEATH_SIGNAL)


def _kill_cell(pid: int, options: EvalOptions) -> None:
    if options.cells is None:  # a user's own cell: faults never run there (`evaluation.command`)
        raise RuntimeError("no fake ROS cell to kill: the backend death runs on the fake cell only")
    options.cells.kill()


#: each backend's injected death
INJECTIONS: dict[str, DeathInjection] = {
    "fake": DeathInjection("its control thread raises", (DEATH_FLAG,), _signal_death, DEATH_EVENT),
    "mujoco": DeathInjection("its physics thread raises", (DEATH_FLAG,), _signal_death, DEATH_EVENT),
    "can": DeathInjection("the emulator stops: every actuator silent", (DEATH_FLAG,), _signal_death, DEATH_EVENT),
    "ros2": DeathInjection("the fake cell's process is SIGKILLed", (), _kill_cell, None, "-daemon-journal.jsonl"),
}
#: the audit event a backend's report must follow when the daemon does not record the injection
EXECUTION_STARTED = "execution_started"


@dataclass
class DeathRun:
    index: int
    #: the execute had not answered when the death was injected
    mid_motion: bool = False
    #: the execute answered with an error or an abort, not success
    execute_failed: bool = False
    #: get_safety_status: the e-stop latched, with a reason
    latched: bool = False
    #: that reason (of the latest latch: the backend's fault, or one the failure caused after it)
    cause: str = ""
    #: get_robot_state was refused after the death, and what it answered
    robot_state_refused: bool = False
    robot_state: str = ""
    plan_refused: bool = False
    #: the plan made before the death, executed after it, was refused
    execute_refused: bool = False
    #: actuating calls that reached the backend after the death (the journal)
    actuations_after: int = 0
    audit_verified: bool = False
    #: the start-up record says the injection was enabled, and the log holds the injection and,
    #: after it, the fault the backend reported (`backend_fault`: the Guard latched on its report)
    audit_records_cause: bool = False
    #: that record's detail: the cause as the backend found it
    fault_record: str = ""
    #: when the force monitor also found the wrench stale (a dead backend stops it too), what the
    #: backend answered when asked whether it was the cause (the `wrench_loss_diagnosis` record's
    #: outcome: "backend_fault" or "wrench_only", the latter a wrong answer here)
    wrench_loss_diagnosis: str | None = None
    detail: str = ""

    @property
    def passed(self) -> bool:
        return self.mid_motion and self.execute_failed and self.latched and self.robot_state_refused \
            and self.plan_refused and self.execute_refused and self.actuations_after == 0 \
            and self.audit_verified and self.audit_records_cause


@dataclass
class BackendDeathResult:
    backend: str
    #: what the death is (`DeathInjection.what`), or why there is none for this backend
    what: str
    runs: list[DeathRun] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return bool(self.runs) and all(r.passed for r in self.runs)

    def report(self) -> dict[str, Any]:
        return {
            "run": True, "passed": self.passed, "backend": self.backend,
            "death": self.what,
            "deaths": len(self.runs), "survived": sum(r.passed for r in self.runs),
            "mid_motion": sum(r.mid_motion for r in self.runs),
            "latched": sum(r.latched for r in self.runs),
            "actuations_after": sum(r.actuations_after for r in self.runs),
            "per_run": [asdict(r) | {"passed": r.passed} for r in self.runs],
        }


async def _die_mid_motion(session: DaemonSession, audit: Path, plan_id: str, reader: JournalReader,
                          rng: np.random.Generator, injection: DeathInjection, options: EvalOptions,
                          run: DeathRun) -> None:
    """Execute `plan_id`; inject the death once the motion's progress passes a random fraction of
    it (or, were the motion answered first, right then); wait for the execute's answer."""
    pid = int(last_startup(audit)["extra"]["pid"])

    def die() -> None:
        reader.new_entries()  # what reached the backend before the death (the execute itself)
        injection.inject(pid, options)

    run.mid_motion, answer = await strike_mid_motion(session, plan_id, float(rng.uniform(*FAULT_AT_PROGRESS)), die)
    if answer is None:
        run.detail += f" the execute did not answer within {FAULT_STEP_TIMEOUT_S:g} s of the death"
        return
    error, done, text = answer
    run.execute_failed = error or done.get("status") == "aborted"
    if not run.execute_failed:
        run.detail += f" the execute answered {done.get('status')!r}: {text[:160]}"
    if not run.mid_motion:
        run.detail += " the death did not find the arm moving (the execute had answered)"


async def _wait_for_report(session: DaemonSession, audit: Path, injection: DeathInjection, run: DeathRun) -> None:
    """Until get_safety_status reports the e-stop latched, with a reason, and the audit log holds
    the fault the backend reported after the injection (`backend_report`), at most
    `LATCH_TIMEOUT_S`. The latch can come first from elsewhere — the failed execute's e-stop, a
    stop that could not be issued, the force monitor finding the wrench stale before the CAN
    backend's RX timeout — and the latest latch is what the status shows: the backend's own
    report is waited for in the log."""
    status: dict[str, Any] = {}
    with anyio.move_on_after(LATCH_TIMEOUT_S):
        while True:
            _, status, _ = await bounded_call(session, "get_safety_status", {})
            if status.get("estopped") and backend_report(audit, injection) is not None:
                break
            await anyio.sleep(LATCH_POLL_S)
    event = status.get("estop_event") or {}
    run.cause = str(event.get("reason", ""))
    run.latched = bool(status.get("estopped")) and bool(run.cause)
    if not run.latched:
        run.detail += f" not latched within {LATCH_TIMEOUT_S:g} s: e-stop {event or None}"


def backend_report(audit: Path, injection: DeathInjection) -> str | None:
    """The detail of the first fault the backend reported after the injection (the Guard's
    `backend_fault` record), or None: no injection, or no report after it (yet)."""
    records = decode_records(audit.read_bytes().split(b"\n")) if audit.exists() else []
    injected = [i for i, r in enumerate(records) if r.get("event") == (injection.audit_event or EXECUTION_STARTED)]
    if not injected:
        return None
    faults = [r for r in records[injected[0]:] if r.get("event") == BACKEND_FAULT]
    return str(faults[0].get("detail") or "") if faults else None


async def _check_refusals(session: DaemonSession, goal: np.ndarray, before_death: str, run: DeathRun) -> None:
    """The state read, a new plan, and the execute of the plan made before the death must be refused."""
    error, _, text = await bounded_call(session, "get_robot_state", {})
    run.robot_state_refused, run.robot_state = error, text[:300]
    if not error:
        run.detail += f" get_robot_state served a state after the death: {text[:160]}"
    error, plan, text = await bounded_call(session, "plan_to_joints", {"joint_positions": goal.tolist(),
                                                                      "preview": False})
    run.plan_refused = error or plan.get("plan_id") is None or plan.get("status") == "rejected"
    if not run.plan_refused:
        run.detail += f" a plan after the death was accepted: {text[:160]}"
    error, done, text = await bounded_call(session, "execute_plan", {"plan_id": before_death})
    run.execute_refused = error or done.get("status") != "succeeded"  # (one that reached the backend: the journal)
    if not run.execute_refused:
        run.detail += f" the execute of a plan made before the death answered {done.get('status')!r}: {text[:160]}"


def _check_audit(audit: Path, injection: DeathInjection, run: DeathRun) -> None:
    """The log verifies, its start-up record says the injection was on, and after the injection it
    holds the fault the backend reported."""
    report = verify_file(audit, hmac_key_from_env())
    run.audit_verified = report.ok
    if not report.ok:
        run.detail += f" the audit log does not verify: line {report.first_bad_line}: {report.reason}"
    enabled = injection.audit_event is None or last_startup(audit).get("extra", {}).get("eval_backend_death") is True
    run.fault_record = backend_report(audit, injection) or ""
    records = decode_records(audit.read_bytes().split(b"\n"))
    diagnoses = [r.get("outcome") for r in records if r.get("event") == "wrench_loss_diagnosis"]
    run.wrench_loss_diagnosis = str(diagnoses[0]) if diagnoses else None
    run.audit_records_cause = enabled and bool(run.fault_record)
    if not run.audit_records_cause:
        run.detail += (f" the audit log does not record it (injection enabled in the start-up record: {enabled}; "
                       "no fault reported by the backend after the injection)")


async def _one_death(options: EvalOptions, directory: Path, index: int, rng: np.random.Generator,
                     injection: DeathInjection) -> DeathRun:
    from armwarden.preflight import load_runtime_model

    run = DeathRun(index)
    name = f"death{index + 1}"
    policy_path = write_policy(options, directory, name, {"rate_limits": UNLIMITED,
                                                          "force.wrench_timeout_s": EVAL_WRENCH_TIMEOUT_S})
    arguments = [*serve_arguments(options, directory, name, policy_path), *injection.serve_flags]
    audit, errlog = directory / f"{name}-audit.jsonl", directory / f"{name}-daemon.err"
    reader = JournalReader(directory / f"{name}{injection.journal_suffix}")
    robot = load_runtime_model(options.policy, str(options.policy_path)).robot
    goal, other = safe_goal(options.policy, robot, rng), safe_goal(options.policy, robot, rng)
    ref: list[DaemonSession] = []
    try:
        with errlog.open("a", encoding="utf-8") as err:
            async with fault_client(daemon_params(arguments), err, ref) as client:
                session = DaemonSession(client)
                ref.append(session)
                await wait_for_state(session)
                plans = []
                for target, scaling in ((goal, DYING), (other, {})):
                    error, plan, text = await bounded_call(
                        session, "plan_to_joints", {"joint_positions": target.tolist(), "preview": False, **scaling})
                    if error or plan.get("plan_id") is None:
                        run.detail += f" plan refused before the death: {text[:160]}"
                        return run
                    plans.append(str(plan["plan_id"]))
                await _die_mid_motion(session, audit, plans[0], reader, rng, injection, options, run)
                await _wait_for_report(session, audit, injection, run)
                await _check_refusals(session, other, plans[1], run)
    except Exception as exc:  # the daemon went away or wedged: the run failed, say how
        run.detail += f" the session broke: {exc!r}"[:300] + last_words(errlog)
    moved = actuations(reader.new_entries())  # the daemon has exited: everything after the death
    run.actuations_after = len(moved)
    if moved:
        run.detail += f" actuations after the death: {', '.join(moved)}"
    if audit.exists():
        _check_audit(audit, injection, run)
    return run


async def run_backend_death(options: EvalOptions, directory: Path, deaths: int) -> BackendDeathResult:
    """`deaths` runs, each on a daemon of its own (a dead backend is only recovered by a restart).
    A backend without an injected death (`INJECTIONS`) fails the fault: nothing showed its death
    is latched, reported and refused."""
    injection = INJECTIONS.get(options.backend)
    if injection is None:
        return BackendDeathResult(options.backend, f"no injected death for the {options.backend} backend")
    result = BackendDeathResult(options.backend, injection.what)
    rng = np.random.default_rng(options.seed + 1)
    for index in range(deaths):
        progress(f"fault: backend death {index + 1}/{deaths} mid-motion ({options.backend}: {injection.what})")
        run = await _one_death(options, directory, index, rng, injection)
        result.runs.append(run)
        progress(f"fault: backend death {index + 1}/{deaths} {'PASS' if run.passed else 'FAIL'}: e-stop "
                 f"{'latched' if run.latched else 'NOT latched'} ({run.cause[:120]}){run.detail}")
    return result


__all__ = ["INJECTIONS", "BackendDeathResult", "DeathInjection", "DeathRun", "backend_report", "run_backend_death"]
