"""Fault injection against the real daemon: kill -9 mid-motion and a restart on the same audit log,
and an audit log that can no longer be written.

Kills: the daemon is started on one audit log again and again. Each run plans a safe move,
executes it and is killed (SIGKILL, the pid from its `startup` record) once the motion's
reported progress passes a random fraction of it. After each kill the log must verify up to its last complete record (a torn last
line is reported, and recovered by the next start); each restart must come up with the e-stop
latched (source `previous_run`) and moving nothing until the reset, which is approved as a human
would; a last start checks the final kill the same way and ends clean.

Audit disk full: a full file system needs root to make, so the daemon runs under a file-size
limit (RLIMIT_FSIZE; CPython ignores SIGXFSZ, so a write past it fails with EFBIG as one on a
full disk fails with ENOSPC: a short write, then an error). A plan made while the log worked is
executed once read-only calls have filled it: the execution must be refused, the state must say
the log is unusable, nothing may actuate, and `estop` must still stop.

The backend dying mid-motion is `armwarden.evaluation.backend_death` (run from here, reported here).
"""

from __future__ import annotations

import os
import signal
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from armwarden.audit import verify_file
from armwarden.audit.chain import hmac_key_from_env
from armwarden.audit.verify import decode_records
from armwarden.daemon.previous_run import PREVIOUS_RUN_SOURCE
from armwarden.evaluation.backend_death import BackendDeathResult, run_backend_death
from armwarden.evaluation.fault_daemon import (
    FAULT_AT_PROGRESS,
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

#: the killed motion's scaling: a slow move (as an operator's careful one), so that the kill finds
#: it moving even on a sped-up simulation (progress is reported every 0.1 s)
SLOW = {"velocity_scaling": 0.05, "acceleration_scaling": 0.05}
#: the audit log's size limit under which the daemon of the disk-full fault runs [bytes]: room for
#: its start-up and a few dozen records
DISK_LIMIT_BYTES = 24_000
#: read-only calls the disk-full fault makes at most to fill the log
FILL_CALLS = 400


@dataclass
class KillRun:
    index: int
    #: the execute had not answered when the kill came
    mid_motion: bool = False
    #: the log verified after the kill, up to its last complete record
    verified: bool = False
    torn_tail: bool = False
    #: the start after this kill came up latched (source previous_run) and refused to move
    latched_after_restart: bool = False
    released: bool = False
    detail: str = ""

    @property
    def passed(self) -> bool:
        return self.mid_motion and self.verified and self.latched_after_restart and self.released


@dataclass
class DiskFullResult:
    filled_after_calls: int = 0
    state_says_unusable: bool = False
    execute_refused: bool = False
    actuations: int = 0
    estop_answered: bool = False
    detail: str = ""

    @property
    def passed(self) -> bool:
        return self.filled_after_calls > 0 and self.state_says_unusable and self.execute_refused \
            and self.actuations == 0 and self.estop_answered


@dataclass
class FaultsResult:
    kills: list[KillRun] = field(default_factory=list)
    #: the kills were asked for (with them: the clean end, the starts unlatched, the full disk)
    kills_asked: bool = True
    disk_full: DiskFullResult | None = None
    #: the backend dying mid-motion (`armwarden.evaluation.backend_death`); None: not asked for
    backend_death: BackendDeathResult | None = None
    #: the runs after the last kill ended with a clean shutdown record
    ended_clean: bool = False
    #: the first start (a new log) and the start after a clean end came up unlatched
    first_start_unlatched: bool = False
    clean_restart_unlatched: bool = False
    final_detail: str = ""

    @property
    def ok(self) -> bool:
        kills = all(k.passed for k in self.kills) and self.ended_clean and self.first_start_unlatched \
            and self.clean_restart_unlatched
        return (kills or not self.kills_asked) and (self.disk_full is None or self.disk_full.passed) \
            and (self.backend_death is None or self.backend_death.passed)

    def report(self) -> dict[str, Any]:
        return {
            "run": True, "passed": self.ok, "kills_asked": self.kills_asked,
            "kills": len(self.kills), "survived": sum(k.passed for k in self.kills),
            "mid_motion": sum(k.mid_motion for k in self.kills),
            "torn_tails": sum(k.torn_tail for k in self.kills),
            "latched_after_restart": sum(k.latched_after_restart for k in self.kills),
            "ended_clean": self.ended_clean, "first_start_unlatched": self.first_start_unlatched,
            "clean_restart_unlatched": self.clean_restart_unlatched, "final_detail": self.final_detail,
            "per_kill": [asdict(k) | {"passed": k.passed} for k in self.kills],
            "disk_full": None if self.disk_full is None else asdict(self.disk_full) | {"passed": self.disk_full.passed},
            "backend_death": None if self.backend_death is None else self.backend_death.report(),
        }


async def _safety(session: DaemonSession) -> dict[str, Any]:
    _, status, _ = await bounded_call(session, "get_safety_status", {})
    return status


async def _check_latch(session: DaemonSession, goal: np.ndarray, run: KillRun | None) -> bool:
    """After a kill (`run`): the start must be latched by the previous run and refuse to plan a
    safe target; then it is reset as an approving human would. Without one (a new log, or after a
    clean end): the start must not be latched. Returns whether the start was as it must be."""
    status = await _safety(session)
    event = status.get("estop_event") or {}
    if run is None:
        return status.get("estopped") is False
    refused, _, text = await bounded_call(session, "plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
    run.latched_after_restart = bool(status.get("estopped")) and event.get("source") == PREVIOUS_RUN_SOURCE \
        and refused and "ESTOP" in text
    if not run.latched_after_restart:
        run.detail += f" restart not latched by the previous run: e-stop {event or None}; plan: {text[:120]}"
    if status.get("estopped"):
        error, reset, text = await bounded_call(session, "reset_estop", {})
        run.released = not error and reset.get("estopped") is False
        if not run.released:
            run.detail += f" reset refused: {text[:160]}"
    return run.latched_after_restart and run.released


async def _kill_mid_motion(session: DaemonSession, audit: Path, goal: np.ndarray, rng: np.random.Generator,
                           run: KillRun) -> None:
    """Plan and execute a safe move; SIGKILL the daemon once the motion's progress passes a random
    fraction of it (or, were the motion answered first, right then)."""
    error, plan, text = await bounded_call(session, "plan_to_joints", {"joint_positions": goal.tolist(), "preview": False,
                                                                **SLOW})
    if error or plan.get("plan_id") is None:
        run.detail += f" plan refused: {text[:160]}"
    pid = int(last_startup(audit)["extra"]["pid"])
    at = float(rng.uniform(*FAULT_AT_PROGRESS))
    # the killed daemon's session sees its pipe close: the answer is that protocol error
    run.mid_motion, _ = await strike_mid_motion(session, str(plan.get("plan_id", "")), at,
                                                lambda: os.kill(pid, signal.SIGKILL))


async def _kills(options: EvalOptions, directory: Path, kills: int, result: FaultsResult) -> None:
    from armwarden.preflight import load_runtime_model

    robot = load_runtime_model(options.policy, str(options.policy_path)).robot
    policy_path = write_policy(options, directory, "faults", {"rate_limits": UNLIMITED,
                                                              "force.wrench_timeout_s": EVAL_WRENCH_TIMEOUT_S})
    arguments = serve_arguments(options, directory, "faults", policy_path)
    audit, errlog = directory / "faults-audit.jsonl", directory / "faults-daemon.err"
    rng = np.random.default_rng(options.seed)
    key = hmac_key_from_env()
    starts = kills + 2  # each kill's run, the run after the last kill (ends clean), one more (must start unlatched)
    for index in range(starts):
        previous = result.kills[-1] if result.kills else None
        run = KillRun(index) if index < kills else None
        progress(f"fault: start {index + 1}/{starts} on one audit log, then "
                 + ("kill -9 mid-motion" if run is not None else "a clean end"))
        ref: list[DaemonSession] = []
        goal = safe_goal(options.policy, robot, rng)
        as_it_must = False
        try:
            with errlog.open("a", encoding="utf-8") as err:
                async with fault_client(daemon_params(arguments), err, ref) as client:
                    session = DaemonSession(client)
                    ref.append(session)
                    await wait_for_state(session)
                    as_it_must = await _check_latch(session, goal, None if index in (0, kills + 1) else previous)
                    if run is not None:
                        await _kill_mid_motion(session, audit, goal, rng, run)
        except Exception as exc:  # after the kill: the pipe closed under the session, as it must
            if run is None or not _gone(audit):
                detail = f"the session broke: {exc!r}"[:300] + last_words(errlog)
                if run is None:
                    result.final_detail += f" start {index + 1}: {detail}"
                else:
                    run.detail += f" {detail}"
        if index == 0:
            result.first_start_unlatched = as_it_must
        if index == kills + 1:
            result.clean_restart_unlatched = as_it_must
        if run is None:
            records = decode_records(audit.read_bytes().split(b"\n"))
            extra = records[-1].get("extra") if records else None
            clean = bool(records) and records[-1].get("event") == "shutdown" and \
                extra == {"arm_stopped": True, "estops_held": []}
            result.ended_clean = clean if index == kills else result.ended_clean and clean
            continue
        report = verify_file(audit, key)
        run.torn_tail = not report.ok and report.reason == "torn last line"
        run.verified = report.ok or run.torn_tail
        if not run.verified:
            run.detail += f" log does not verify after the kill: line {report.first_bad_line}: {report.reason}"
        if not run.mid_motion:
            run.detail += " the kill did not find the arm moving (the execute had answered)"
        result.kills.append(run)
        progress(f"fault: kill {index + 1}/{kills} {'mid-motion' if run.mid_motion else 'after the motion'}; "
                 f"log {'verifies' if report.ok else 'has a torn tail' if run.torn_tail else 'BROKEN'}")


def _gone(audit: Path) -> bool:
    """Whether the daemon of the last startup record is no longer running."""
    try:
        os.kill(int(last_startup(audit)["extra"]["pid"]), 0)
    except ProcessLookupError:
        return True
    except (RuntimeError, KeyError, ValueError):  # no startup record: it never started
        return False
    return False


async def _disk_full(options: EvalOptions, directory: Path) -> DiskFullResult:
    result = DiskFullResult()
    policy_path = write_policy(options, directory, "diskfull", {"rate_limits": UNLIMITED,
                                                                "force.wrench_timeout_s": EVAL_WRENCH_TIMEOUT_S})
    arguments = serve_arguments(options, directory, "diskfull", policy_path)
    reader = JournalReader(directory / "diskfull-journal.jsonl")
    progress(f"fault: the audit log's file limited to {DISK_LIMIT_BYTES} bytes (a full disk)")
    from armwarden.preflight import load_runtime_model

    robot = load_runtime_model(options.policy, str(options.policy_path)).robot
    goal = safe_goal(options.policy, robot, np.random.default_rng(options.seed))
    ref: list[DaemonSession] = []
    errlog = directory / "diskfull-daemon.err"
    with errlog.open("a", encoding="utf-8") as err:
        return await _fill_the_log(arguments, err, ref, goal, reader, result)


async def _fill_the_log(arguments: list[str], err: TextIO, ref: list[DaemonSession], goal: np.ndarray,
                        reader: JournalReader, result: DiskFullResult) -> DiskFullResult:
    async with fault_client(daemon_params(arguments, DISK_LIMIT_BYTES), err, ref) as client:
        session = DaemonSession(client)
        ref.append(session)
        await wait_for_state(session)
        error, plan, text = await bounded_call(session, "plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
        if error or plan.get("plan_id") is None:
            result.detail = f"plan refused before the log filled: {text[:160]}"
            return result
        for call in range(1, FILL_CALLS + 1):
            status = await _safety(session)
            if status.get("audit_ok") is False:
                result.filled_after_calls = call
                result.state_says_unusable = bool(status.get("audit_error"))
                break
        else:
            result.detail = f"the log still took records after {FILL_CALLS} calls"
            return result
        reader.new_entries()
        error, done, text = await bounded_call(session, "execute_plan", {"plan_id": plan["plan_id"]})
        # refused saying why: a refusal (AUDIT_UNAVAILABLE) or, where even that cannot be recorded,
        # an error naming the log; either way nothing may have moved (counted below)
        result.execute_refused = (error or done.get("status") != "succeeded") and \
            ("AUDIT_UNAVAILABLE" in text or "audit log" in text)
        if not result.execute_refused:
            result.detail = f"execute with the log full: {text[:160]}"
        result.actuations = len(actuations(reader.new_entries()))
        error, stopped, text = await bounded_call(session, "estop", {"reason": "eval: audit disk full"})
        result.estop_answered = not error and stopped.get("estopped") is True
        if not result.estop_answered:
            result.detail = f"estop with the log full: {text[:160]}"
    return result


async def run_faults(options: EvalOptions, directory: Path, kills: int, disk_full: bool = True,
                     deaths: int = 0) -> FaultsResult:
    """`kills` kills (0: none, and no full disk either), the full disk, and `deaths` backend deaths."""
    result = FaultsResult(kills_asked=kills > 0)
    if kills > 0:
        await _kills(options, directory, kills, result)
        if disk_full:
            result.disk_full = await _disk_full(options, directory)
    if deaths > 0:
        result.backend_death = await run_backend_death(options, directory, deaths)
    return result
