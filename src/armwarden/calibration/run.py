"""Running a contact calibration: safe motions through the whole server, the observer recorded.

Policy, robot model, backend, audit log and Guard are built by the daemon's own start-up
(`armwarden.daemon.startup`: the same builders, the same audit key, as `armwarden serve`). Every
motion goes the way any client's does — `plan_to_joints`, the envelope's checks, approval,
`execute_plan` with the force monitor on — through the official MCP client in-process, so the Guard
enforces the policy and the audit log records each call. The human approved the calibration as a
whole before it started; that approval answers each motion's question, under the operator's name.
Only plans the envelope passes outright (`ok`) run; one it rejects or would ask about is skipped.

Beside the Guard's own monitor a second observer over the same joint states records the residual
per joint and the joint velocities at the monitor's rate, with no friction allowance, so the fit
starts from what the arm really reads. A stop, an e-stop (SIGUSR1, or Ctrl-C / SIGTERM, each of
which latches it on its own thread as SIGUSR1 does for `serve`), a contact or a refusal ends the
calibration: nothing more moves, and the result says why.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import re
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import numpy as np
from mcp import Client
from mcp import types as mcp_types

from armwarden.audit import AuditWriteError
from armwarden.backends.base import Backend
from armwarden.calibration.friction_fit import DEFAULT_MARGIN, JointRecommendation, recommend
from armwarden.core.state import JointState
from armwarden.daemon.shutdown import close_assembly
from armwarden.daemon.startup import SWITCH_INTERVAL_S, assemble, freeze_long_lived_objects, open_assembly
from armwarden.guard import Guard
from armwarden.policy import Policy, parse_policy, policy_digest
from armwarden.policy.joint_torques import provisional_limit_nm
from armwarden.robot import build_robot
from armwarden.robot.model import RobotModel
from armwarden.safety.contact_observer import ContactObserver
from armwarden.safety.contact_source import JointTorqueContact, observer_for
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
    #: the policy's friction allowance) [N·m]; a cross-check of the recorder's residuals
    monitor_peaks_nm: list[float] = field(default_factory=list)
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


class _Recorder:
    """The calibration's own observer over the joint states, sampled at the monitor's rate: each
    residual with the velocities of the very state it came from."""

    def __init__(self, backend: Backend, observer: ContactObserver, policy: Policy) -> None:
        self._backend = backend
        self._state: JointState | None = None
        self._contact = JointTorqueContact(self._read_state, observer, policy.robot.joint_names,
                                           backend.capabilities.time_scale, max_unobserved_s=math.inf)
        self._period_s = 1.0 / policy.force.monitor_rate_hz
        self.velocities: list[np.ndarray] = []
        self.residuals: list[np.ndarray] = []
        self._last_stamp = -math.inf

    async def _read_state(self) -> JointState:
        self._state = await self._backend.read_joint_state()
        return self._state

    async def run(self) -> None:
        while True:
            reading = await self._contact.read()
            torques = getattr(reading, "external_torques_nm", None)
            state = self._state
            if (reading is not None and torques is not None and state is not None and reading.stamp > self._last_stamp
                    and np.all(np.isfinite(torques))):
                self._last_stamp = reading.stamp
                self.velocities.append(np.asarray(state.velocities, dtype=float))
                self.residuals.append(np.asarray(torques, dtype=float))
            await anyio.sleep(self._period_s)


def _without_friction(observer: ContactObserver, robot: RobotModel) -> ContactObserver:
    settings = dataclasses.replace(observer.settings, coulomb_nm=(0.0,) * robot.nq, viscous_nms=(0.0,) * robot.nq)
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
    recorder: _Recorder | None = None
    started = False
    try:
        backend, guard, audit = assembly.backend, assembly.guard, assembly.audit
        if not backend.capabilities.joint_torques:
            raise ValueError(f"backend {backend.name} measures no joint torques: there is nothing to calibrate")
        recorder = _Recorder(backend, _without_friction(observer_for(policy, parts.state_robot), parts.state_robot),
                             policy)
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
            await _move(options, policy, assembly.server, guard, recorder, goals, result, progress)
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
    if result.stopped is None and result.executed and recorder is not None and recorder.residuals:
        result.recommendations = recommend(policy.robot.joint_names, np.array(recorder.velocities),
                                           np.array(recorder.residuals), options.margin)
        result.section = _section(policy, result.recommendations)
    return result


def _runs(summary: dict[str, Any]) -> bool:
    """Whether a plan is one the calibration's approval covers: the envelope passed it outright, or
    it asks only because the policy asks for every motion (`approval.mode: always`). A plan with a
    finding (a soft violation a human should weigh on its own) is skipped."""
    return summary.get("status") == "ok" or (summary.get("status") == "needs_approval"
                                             and not summary.get("violations"))


async def _move(options: CalibrationOptions, policy: Policy, server: ArmWardenServer, guard: Guard,
                recorder: _Recorder, goals: list[list[float]], result: CalibrationResult,
                progress: Callable[[str], None]) -> None:
    """The motions through the MCP client, recorded; the first stop or refusal ends them."""

    async def approve(context: Any, params: mcp_types.ElicitRequestParams) -> mcp_types.ElicitResult:
        return mcp_types.ElicitResult(action="accept", content={"approve": True, "operator": options.operator})

    async with Client(server.mcp, mode="legacy", elicitation_callback=approve) as client, \
            anyio.create_task_group() as group:
        group.start_soon(recorder.run)
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
            done = await _call(client, "execute_plan", {"plan_id": summary["plan_id"]})
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
        group.cancel_scope.cancel()


def _section(policy: Policy, found: list[JointRecommendation]) -> dict[str, Any]:
    """The `force.joint_torques` section with the recommendations (the rest as the policy had it)."""
    current = policy.force.joint_torques
    assert current is not None
    section = current.model_dump(mode="json")
    section["max_external_torque_nm"] = {r.name: r.limit_nm for r in found}
    section["friction_coulomb_nm"] = {r.name: r.coulomb_nm for r in found if r.coulomb_nm > 0}
    section["friction_viscous_nms"] = {r.name: r.viscous_nms for r in found if r.viscous_nms > 0}
    return section
