"""The backend dying mid-motion, on ROS 2: the fake cell's process is SIGKILLed while a slow
approved motion runs (issue 30, item 5: "the backend dying mid-motion ... cell process").

A real cell dies that way when its driver or its host crashes: no topic, no feedback, no result
ever again. The daemon must notice it by itself (the joint states stop, the action server
vanishes), answer the execute as a backend fault, latch the e-stop, report it in
`get_safety_status` (latched, source `backend_fault`, the fault listed) and refuse what follows:
a new plan, and the execute of a plan made before the death. Nothing may reach the backend after
the kill: the daemon's own actuation journal (the backend wrapper) must show no actuation past it
(the cell, being dead, journals nothing).

Runs on the fake cell only (`EvalOptions.cells`): `run_cell_death` starts a daemon on a cell of
its own, kills that cell, and leaves the cell for the next daemon to start afresh.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import anyio
import numpy as np
from mcp import Client
from mcp.client.stdio import stdio_client

from armwarden.evaluation import runner
from armwarden.evaluation.daemon_process import DAEMON_COMMAND, stdio_params
from armwarden.evaluation.journal import JournalReader, actuations
from armwarden.evaluation.runner import (
    EVAL_WRENCH_TIMEOUT_S,
    SCENARIO_TIMEOUT_S,
    UNLIMITED,
    DaemonSession,
    EvalOptions,
    approver,
    safe_goal,
    serve_arguments,
    wait_for_state,
    write_policy,
)

#: the motion the cell dies under: slow, as an operator's careful move (about 10 s on the FR3),
#: so that the kill finds it moving
SLOW = {"velocity_scaling": 0.05, "acceleration_scaling": 0.05}
#: the cell is killed once the motion's reported progress passes this fraction of it
KILL_AT_PROGRESS = 0.1
#: how long the motion may take to start, and the daemon to answer once the cell is gone [s]
STEP_TIMEOUT_S = 60.0
#: the name of this fault's daemon (its policy, audit log and journals in the directory)
NAME = "cell_death"


@dataclass
class CellDeathResult:
    #: the execute had not answered when the cell was killed
    mid_motion: bool = False
    #: the execute was answered (not hung) and as a backend fault
    answered_as_fault: bool = False
    #: get_safety_status: e-stop latched with source backend_fault, the fault listed
    latched: bool = False
    reported: bool = False
    #: a new plan and the execute of a plan made before the death were refused
    plan_refused: bool = False
    execute_refused: bool = False
    #: actuations the backend wrapper journaled after the kill
    actuations_after_kill: int = 0
    detail: str = ""

    @property
    def passed(self) -> bool:
        return self.mid_motion and self.answered_as_fault and self.latched and self.reported \
            and self.plan_refused and self.execute_refused and self.actuations_after_kill == 0

    def report(self) -> dict[str, Any]:
        return asdict(self) | {"passed": self.passed}


async def _call(session: DaemonSession, tool: str, arguments: dict[str, Any]) -> tuple[bool, dict[str, Any], str]:
    """`call_raw` within `SCENARIO_TIMEOUT_S`: a daemon wedged by the dead cell fails the fault, it does not hang."""
    try:
        with anyio.fail_after(SCENARIO_TIMEOUT_S):
            return await session.call_raw(tool, arguments)
    except TimeoutError:
        return True, {}, f"{tool}: no answer within {SCENARIO_TIMEOUT_S:g} s"


async def run_cell_death(options: EvalOptions, directory: Path) -> CellDeathResult:
    """Kill the fake cell mid-motion under a daemon and check what the daemon does (module docstring)."""
    if options.cells is None:
        raise ValueError("the cell-death fault runs on the fake ROS cell only (--backend ros2 without a config)")
    from armwarden.preflight import load_runtime_model

    cells = options.cells
    result = CellDeathResult()
    robot = load_runtime_model(options.policy, str(options.policy_path)).robot
    rng = np.random.default_rng(options.seed)
    moving_goal, other_goal = safe_goal(options.policy, robot, rng), safe_goal(options.policy, robot, rng)
    policy_path = write_policy(options, directory, NAME, {"rate_limits": UNLIMITED,
                                                          "force.wrench_timeout_s": EVAL_WRENCH_TIMEOUT_S})
    arguments = serve_arguments(options, directory, NAME, policy_path)  # starts this daemon's cell
    backend_journal = JournalReader(directory / f"{NAME}-daemon-journal.jsonl")
    runner.progress("fault: the fake ROS cell's process SIGKILLed mid-motion")
    ref: list[DaemonSession] = []
    with (directory / f"{NAME}-daemon.err").open("a", encoding="utf-8") as errlog:
        params = stdio_params(DAEMON_COMMAND, arguments)
        async with Client(stdio_client(params, errlog=errlog), mode="legacy", elicitation_callback=approver(ref)) as c:
            session = DaemonSession(c)
            ref.append(session)
            await wait_for_state(session)
            _, before, text = await _call(session, "plan_to_joints", {"joint_positions": other_goal.tolist(),
                                                                       "preview": False})
            error, plan, text = await _call(session, "plan_to_joints", {"joint_positions": moving_goal.tolist(),
                                                                         "preview": False, **SLOW})
            if error or plan.get("plan_id") is None or before.get("plan_id") is None:
                result.detail = f"plan refused before the fault: {text[:160]}"
                return result
            answer = await _execute_and_kill(session, plan["plan_id"], cells.kill, result)
            backend_journal.new_entries()  # what reached the backend up to the answer: the motion itself
            result.answered_as_fault = answer is not None and answer[0] and "BACKEND_FAULT" in answer[1]
            if not result.answered_as_fault:
                result.detail += f" execute answered: {None if answer is None else answer[1][:200]}"
            _, status, _ = await _call(session, "get_safety_status", {})
            event = status.get("estop_event") or {}
            result.latched = status.get("estopped") is True and event.get("source") == "backend_fault"
            result.reported = any("fault" in str(f) for f in status.get("faults") or [])
            if not (result.latched and result.reported):
                result.detail += f" safety status: estopped {status.get('estopped')}, event {event or None}, " \
                                 f"faults {status.get('faults')}"
            error, _, text = await _call(session, "plan_to_joints", {"joint_positions": other_goal.tolist(),
                                                                      "preview": False})
            result.plan_refused = error
            if not error:
                result.detail += f" a plan after the death was accepted: {text[:160]}"
            error, done, text = await _call(session, "execute_plan", {"plan_id": before["plan_id"]})
            result.execute_refused = error or done.get("status") in ("rejected", "aborted")
            if not result.execute_refused:
                result.detail += f" a plan made before the death executed: {text[:160]}"
            result.actuations_after_kill = len(actuations(backend_journal.new_entries()))
    runner.progress(f"fault: cell killed {'mid-motion' if result.mid_motion else 'NOT mid-motion'}; "
             f"{'passed' if result.passed else 'FAILED:' + result.detail}")
    return result


async def _execute_and_kill(session: DaemonSession, plan_id: str, kill: Callable[[], None],
                            result: CellDeathResult) -> tuple[bool, str] | None:
    """Execute `plan_id`; once its progress passes `KILL_AT_PROGRESS`, `kill()` the cell. Returns the
    execute's answer (is an error, text), None when none came within `STEP_TIMEOUT_S` after the kill."""
    moving, answered = anyio.Event(), anyio.Event()
    answer: list[tuple[bool, str]] = []

    async def on_progress(progress: float, total: float | None, message: str | None) -> None:
        if KILL_AT_PROGRESS * (total or 1.0) <= progress < (total or 1.0):
            moving.set()

    async def execute() -> None:
        try:
            done = await session.client.call_tool("execute_plan", {"plan_id": plan_id}, progress_callback=on_progress)
            text = " ".join(getattr(block, "text", "") for block in done.content)
            status = (done.structured_content or {}).get("status")
            answer.append((bool(done.is_error) or status != "succeeded", f"{status}: {text}"))
        except Exception as exc:  # an MCP error reply
            answer.append((True, f"protocol error: {exc}"))
        finally:
            answered.set()
            moving.set()

    async with anyio.create_task_group() as group:
        group.start_soon(execute)
        with anyio.move_on_after(STEP_TIMEOUT_S):
            await moving.wait()
        result.mid_motion = not answered.is_set()
        if not result.mid_motion:
            result.detail += " the motion was answered before the cell could be killed;"
        kill()
        with anyio.move_on_after(STEP_TIMEOUT_S):
            await answered.wait()
        group.cancel_scope.cancel()
    return answer[0] if answer else None


__all__ = ["CellDeathResult", "run_cell_death"]
