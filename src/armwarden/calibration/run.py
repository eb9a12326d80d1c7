"""Running a contact calibration: safe motions through the whole server, the observer recorded.

Policy, robot model, backend, audit log and Guard are built by the daemon's own start-up
(`armwarden.daemon.startup`: the same builders, the same audit key, as `armwarden serve`). Every
motion goes the way any client's does — `plan_to_joints`, the envelope's checks, approval,
`execute_plan` with the force monitor on — through the official MCP client in-process, so the Guard
enforces the policy and the audit log records each call. The human approved the calibration as a
whole before it started; that approval answers each motion's question, under the operator's name.
Only plans the envelope passes outright (`ok`) run; one it rejects or would ask about is skipped.

The Guard drives the backend through a `RecordingBackend`, which keeps every joint state the
contact monitor reads during each motion. Afterwards those very samples are replayed through
observers of the same construction (`recording.replay`): with no friction allowance, so the fit
starts from what the arm really reads; with the policy's, to cross-check the monitor's own peaks;
and with the fitted friction, to see what a monitor with the recommended section would have read.
A stop, an e-stop (SIGUSR1, or Ctrl-C / SIGTERM, each of which latches it on its own thread as
SIGUSR1 does for `serve`), a contact or a refusal ends the calibration: nothing more moves, and
the result says why.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import re
import signal
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import numpy as np
from mcp import Client
from mcp import types as mcp_types

from armwarden.audit import AuditWriteError
from armwarden.calibration.friction_fit import (
    DEFAULT_MARGIN,
    JointRecommendation,
    fit_friction,
    force_limit_for,
    recommend,
)
from armwarden.calibration.recording import RecordingBackend, Replay, replay
from armwarden.daemon.shutdown import close_assembly
from armwarden.daemon.startup import SWITCH_INTERVAL_S, assemble, freeze_long_lived_objects, open_assembly
from armwarden.guard import Guard
from armwarden.policy import Policy, parse_policy, policy_digest
from armwarden.policy.joint_torques import provisional_limit_nm
from armwarden.robot import build_robot
from armwarden.robot.model import RobotModel
from armwarden.safety.contact_observer import ContactObserver
from armwarden.safety.contact_source import observer_for
from armwarden.server.app import ArmWardenServer
from armwarden.stopchannel.external import ExternalStops
from armwarden.stopchannel.signals import SignalStop

__all__ = ["CalibrationOptions", "CalibrationResult", "calibration_goals", "calibration_policy", "run_calibration"]

#: each joint's goal is drawn within ± this of home [rad] (and inside the limits and their margin)
GOAL_SPREAD_RAD = 0.4
#: what the calibration's audit records and its e-stops name as their source
PRINCIPAL = "calibrate-contact"
#: signals that stop the calibration: each latches the e-stop and stops the arm from its own thread
STOP_SIGNALS = (signal.SIGUSR1, signal.SIGINT, signal.SIGTERM)


@dataclass(frozen=True)
class CalibrationOptions:
    policy: Policy
    backend: str
    backend_config: Path | None = None
    motions: int = 30
    seed: int = 0
    margin: float = DEFAULT_MARGIN
    operator: str = "calibration"
    audit_log: Path = Path("armwarden-audit.jsonl")


@dataclass
class CalibrationResult:
    """What ran and what it recommends; `stopped` says why the calibration ended early (None: it ran)."""

    planned: int = 0
    #: the random motions that ran (the return home not counted: it may not move at all)
    executed: int = 0
    returned_home: bool = False
    #: per joint, the largest external torque the Guard's own monitor estimated in any motion (with
    #: the policy's friction allowance) [N·m], as its execution results report it
    monitor_peaks_nm: list[float] = field(default_factory=list)
    #: ... and the same, replayed from the recorded samples: the two match when the samples are the monitor's
    replayed_peaks_nm: list[float] = field(default_factory=list)
    #: the largest trusted TCP force estimate with the fitted friction allowed for [N], and its limit
    peak_force_n: float = 0.0
    max_contact_force_n: float = math.inf
    #: the recommended `max_tcp_force_n` [N] (None: none fits under `max_contact_force_n`)
    force_limit_n: float | None = None
    skipped: list[str] = field(default_factory=list)
    stopped: str | None = None
    recommendations: list[JointRecommendation] = field(default_factory=list)
    section: dict[str, Any] = field(default_factory=dict)


def calibration_policy(policy: Policy, robot: RobotModel) -> Policy:
    """`policy` monitoring contact from joint torques (the calibration's subject); a policy without
    limits for them gets provisional ones from the joints' effort limits."""
    document = policy.model_dump(mode="json")
    force = document["force"]
    force["source"] = "joint_torques"
    if force.get("joint_torques") is None:
        model = robot.model
        force["joint_torques"] = {"max_external_torque_nm": {
            name: provisional_limit_nm(float(model.effortLimit[model.joints[model.getJointId(name)].idx_v]))
            for name in policy.robot.joint_names}}
    return parse_policy(document, source="calibration")


def calibration_goals(policy: Policy, count: int, seed: int) -> list[list[float]]:
    """The `count` seeded random joint goals, then home: each joint within ±`GOAL_SPREAD_RAD` of
    home, and inside its limits by the policy's margin plus 0.05 rad (never a plan that asks)."""
    rng = np.random.default_rng(seed)
    home = np.asarray(policy.robot.home_joint_positions, dtype=float)
    margin = policy.motion.joint_limit_margin_rad + 0.05
    lower = np.array([lim.min for lim in policy.robot.joint_limits.values()]) + margin
    upper = np.array([lim.max for lim in policy.robot.joint_limits.values()]) - margin
    goals = [np.clip(home + rng.uniform(-GOAL_SPREAD_RAD, GOAL_SPREAD_RAD, size=home.shape), lower, upper).tolist()
             for _ in range(count)]
    return [*goals, home.tolist()]


def _with_friction(observer: ContactObserver, robot: RobotModel, coulomb_nm: Sequence[float],
                   viscous_nms: Sequence[float]) -> ContactObserver:
    """A fresh observer like `observer`, allowing for this friction instead of its own."""
    settings = dataclasses.replace(observer.settings, coulomb_nm=tuple(coulomb_nm), viscous_nms=tuple(viscous_nms))
    return ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, settings)


def _text(result: mcp_types.CallToolResult) -> str:
    return " ".join(getattr(block, "text", "") for block in result.content)


#: how long a call refused by the policy's rate limits is retried before the calibration gives up [s]
RATE_LIMIT_PATIENCE_S = 120.0


async def _call(client: Client, tool: str, arguments: dict[str, Any]) -> mcp_types.CallToolResult:
    """`tool`, retried while the policy's rate limit refuses it (the calibration keeps to the limits
    every client does; it waits the time the refusal names)."""
    waited = 0.0
    while True:
        result = await client.call_tool(tool, arguments)
        text = _text(result)
        if not (result.is_error and "[RATE_LIMITED]" in text) or waited > RATE_LIMIT_PATIENCE_S:
            return result
        match = re.search(r"retry in ([0-9.]+) s", text)
        pause = min(10.0, float(match.group(1)) if match else 1.0) + 0.05
        await anyio.sleep(pause)
        waited += pause


async def run_calibration(options: CalibrationOptions, progress: Callable[[str], None] = lambda _: None,
                          ) -> CalibrationResult:
    """Run the motions, then fit; see the module docstring. Raises (an `ArmWardenError` or
    `ValueError`) only before anything moved; a failure once the motions began ends the
    calibration like a stop (`CalibrationResult.stopped`)."""
    robot = build_robot(options.policy)
    policy = calibration_policy(options.policy, robot)
    if policy.dry_run:
        raise ValueError("the policy is a dry run: nothing would move, so there is nothing to calibrate")
    parts = assemble(policy, options.backend, None if options.backend_config is None else str(options.backend_config),
                     str(options.audit_log))
    try:
        assembly = await open_assembly(parts)
    except BaseException:
        parts.audit.close()
        raise
    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)  # as `serve`: planning never holds a stop up for long
    freeze_long_lived_objects()  # as `serve`: no long collection stalls the monitor or a simulator's clock
    result = CalibrationResult()
    started = False
    recording: RecordingBackend | None = None
    try:
        backend, guard, audit = assembly.backend, assembly.guard, assembly.audit
        # the reader the Guard's contact monitor builds for each execution reads through the runner's
        # backend, and nothing else there reads joint states: wrapped, it keeps the monitor's samples
        recording = RecordingBackend(guard.runner.backend)
        guard.runner.backend = recording
        if not backend.capabilities.joint_torques:
            raise ValueError(f"backend {backend.name} measures no joint torques: there is nothing to calibrate")
        external = ExternalStops(guard.stopper, audit, asyncio.get_running_loop())
        stops = [SignalStop(external.latch_and_stop_for("signal"), on_event=external.record, signum=signum).start()
                 for signum in STOP_SIGNALS]
        try:
            goals = calibration_goals(policy, options.motions, options.seed)
            await audit.append_async(
                "calibration_started", principal=PRINCIPAL, operator=options.operator, outcome="approved",
                detail=f"calibrate-contact: {len(goals) - 1} motions (seed {options.seed}) and back home, approved "
                       "once on the terminal",
                extra={"backend": options.backend, "policy_digest": policy_digest(policy), "margin": options.margin})
            started = True
            await _move(options, policy, assembly.server, guard, recording, goals, result, progress)
        except Exception as exc:
            if not started:
                raise
            result.stopped = f"{type(exc).__name__}: {exc}"
        finally:
            for stop in stops:
                stop.close()
    finally:
        lost: str | None = None
        with anyio.CancelScope(shield=True):  # the arm stops and the log closes, whatever ended the run
            why = "calibrate-contact finished" if result.stopped is None else f"calibrate-contact stopped: {result.stopped}"
            try:
                if started:
                    await assembly.audit.append_async(
                        "calibration_finished", principal=PRINCIPAL, operator=options.operator,
                        outcome="stopped" if result.stopped else "ok",
                        detail=result.stopped or f"{result.executed} motions ran, {len(result.skipped)} skipped, "
                               f"{'back home' if result.returned_home else 'not back home'}")
            except AuditWriteError as exc:
                lost = f"calibration_finished: {exc}"
            lost = await close_assembly(assembly, why) or lost
        sys.setswitchinterval(switch_interval)
        if lost is not None:
            raise AuditWriteError(f"the final audit record could not be written: {lost}")
    if result.stopped is None and result.executed and recording is not None and recording.states:
        await _recommend(options, policy, parts.state_robot, recording, result)
    return result


async def _recommend(options: CalibrationOptions, policy: Policy, robot: RobotModel, recording: RecordingBackend,
                     result: CalibrationResult) -> None:
    """Replay the monitor's samples, fit friction, and recommend (see the module docstring)."""
    names, time_scale = policy.robot.joint_names, recording.capabilities.time_scale
    guards = observer_for(policy, robot)
    zeros = (0.0,) * len(names)

    async def replay_all(coulomb: Sequence[float], viscous: Sequence[float]) -> list[Replay]:
        return [await replay(states, _with_friction(guards, robot, coulomb, viscous), names, time_scale)
                for states in recording.states.values()]

    policy_friction = await replay_all(guards.settings.coulomb_nm, guards.settings.viscous_nms)
    result.replayed_peaks_nm = np.max([r.peaks_nm for r in policy_friction], axis=0).tolist()
    free = await replay_all(zeros, zeros)
    velocities = np.concatenate([r.velocities for r in free])
    residuals = np.concatenate([r.residuals for r in free])
    fits = [fit_friction(velocities[:, j], residuals[:, j]) for j in range(len(names))]
    fitted = await replay_all([c for c, _ in fits], [b for _, b in fits])
    result.recommendations = recommend(names, velocities, residuals, options.margin,
                                       peaks_after_friction_nm=np.max([r.peaks_nm for r in fitted], axis=0).tolist())
    result.peak_force_n = max(r.peak_force_n for r in fitted)
    result.max_contact_force_n = policy.force.max_contact_force_n
    result.force_limit_n = force_limit_for(result.peak_force_n, options.margin, result.max_contact_force_n)
    result.section = _section(policy, result.recommendations, result.force_limit_n)


def _runs(summary: dict[str, Any]) -> bool:
    """Whether a plan is one the calibration's approval covers: the envelope passed it outright, or
    it asks only because the policy asks for every motion (`approval.mode: always`). A plan with a
    finding (a soft violation a human should weigh on its own) is skipped."""
    return summary.get("status") == "ok" or (summary.get("status") == "needs_approval"
                                             and not summary.get("violations"))


async def _move(options: CalibrationOptions, policy: Policy, server: ArmWardenServer, guard: Guard,
                recording: RecordingBackend, goals: list[list[float]], result: CalibrationResult,
                progress: Callable[[str], None]) -> None:
    """The motions through the MCP client, each one's samples recorded; the first stop or refusal ends them."""

    async def approve(context: Any, params: mcp_types.ElicitRequestParams) -> mcp_types.ElicitResult:
        return mcp_types.ElicitResult(action="accept", content={"approve": True, "operator": options.operator})

    async with Client(server.mcp, mode="legacy", elicitation_callback=approve) as client:
        scaling = {"velocity_scaling": policy.motion.max_velocity_scaling,
                   "acceleration_scaling": policy.motion.max_acceleration_scaling}
        for index, goal in enumerate(goals):
            event = guard.latch.current_event
            if event is not None:  # latched between two motions (a signal, the stop channel, ...)
                result.stopped = f"before motion {index + 1}: e-stop latched: {event.reason}"
                break
            result.planned += 1
            planned = await _call(client, "plan_to_joints", {"joint_positions": goal, "preview": False, **scaling})
            summary = planned.structured_content or {}
            if planned.is_error:  # a refusal (an e-stop, a stale state, ...), not the envelope's verdict
                result.stopped = f"motion {index + 1}: {_text(planned)}"
                break
            if not _runs(summary):
                found = "; ".join(f"{v.get('code')}: {v.get('detail')}" for v in summary.get("violations") or [])
                result.skipped.append(f"motion {index + 1}: {summary.get('status')}" + (f" ({found})" if found else ""))
                continue
            if summary.get("force_monitoring") is not True:  # a calibration nothing watches is no calibration
                result.stopped = f"motion {index + 1}: the plan would run without contact monitoring"
                break
            recording.motion = index
            try:
                done = await _call(client, "execute_plan", {"plan_id": summary["plan_id"]})
            finally:
                recording.motion = None
            if done.is_error or (done.structured_content or {}).get("status") != "succeeded":
                result.stopped = f"motion {index + 1}: {_text(done) or done.structured_content}"
                break
            peaks = (done.structured_content or {}).get("max_external_torques_nm") or []
            result.monitor_peaks_nm = [max(pair) for pair in zip(result.monitor_peaks_nm or [0.0] * len(peaks), peaks,
                                                                 strict=True)]
            if index < len(goals) - 1:
                result.executed += 1
            else:
                result.returned_home = True
            progress(f"motion {index + 1}/{len(goals)} done")


def _section(policy: Policy, found: list[JointRecommendation], force_limit_n: float | None) -> dict[str, Any]:
    """The `force.joint_torques` section with the recommendations (the rest as the policy had it)."""
    current = policy.force.joint_torques
    assert current is not None
    section = current.model_dump(mode="json")
    section["max_external_torque_nm"] = {r.name: r.limit_nm for r in found}
    section["max_tcp_force_n"] = force_limit_n
    section["friction_coulomb_nm"] = {r.name: r.coulomb_nm for r in found if r.coulomb_nm > 0}
    section["friction_viscous_nms"] = {r.name: r.viscous_nms for r in found if r.viscous_nms > 0}
    return section
