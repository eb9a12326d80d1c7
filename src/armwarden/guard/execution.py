"""Running one checked, approved plan on the backend: the only place a trajectory is handed over.

The Guard decides *whether* a plan may run (admission, ordering, the execution slot); this
module *runs* it: it arms the force monitor on the policy's contact source (`contact_source`: a
force/torque sensor, or the observer over the motors' measured joint torques), refusing to move
without a usable reading, or from a contact already over twice the limit, writes `execution_started` to the audit log before the
arm moves (a crash mid-motion still leaves a trace), then executes while the monitor watches and
progress streams, and ends every path with the arm stopped or the e-stop latched:

- force limit crossed (while moving or in one last sample after) → e-stop, FORCE_LIMIT;
- no usable wrench (missing, slow, frozen, stale) → e-stop at once with a neutral cause ("the
  wrench stream was lost; checking whether the backend failed", source `wrench_lost`: no force was
  measured, so no force violation is latched), then the backend is asked whether it is the cause
  (a dead thread, a dead cell: `Backend.fault_behind_stale_data`, which may take the backend's
  fault-detection time) and the finding is audited (`wrench_loss_diagnosis`) → BACKEND_FAULT
  naming it (e-stop again, for the fault), otherwise FORCE_LIMIT saying the wrench stream was
  lost. The latch comes first: while the question is open nothing else actuates (a gripper
  action or a control action from another client meets the e-stop, not a stopped arm);
- backend fault mid-motion → e-stop, BACKEND_FAULT;
- the call cancelled (client cancel, disconnect, timeout) → stop (e-stop if the stop fails),
  recorded as aborted with the time the arm actually moved.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import anyio
import numpy as np

from armwarden.approval.decision import Approval
from armwarden.approval.plans import StoredPlan
from armwarden.backends.base import Backend
from armwarden.backends.values import ExecutionResult
from armwarden.core.errors import BackendError, RefusalCode, SafetyRefusal
from armwarden.policy import Policy
from armwarden.results import ExecutionReport
from armwarden.robot.model import RobotModel
from armwarden.safety.contact_source import (
    ContactSource,
    JointTorqueContact,
    choose_contact_source,
    observer_for,
    unintegrable_joint_states,
)
from armwarden.safety.estop import EStopEvent, EStopLatch
from armwarden.safety.force import ForceLimits, ForceMonitor, ForceViolation

logger = logging.getLogger(__name__)

ProgressReporter = Callable[[float], Awaitable[None]]
#: latch the e-stop: (reason, source, force violation details)
EStop = Callable[..., Awaitable[Any]]
#: stop arm and gripper for a call that cannot; None if the stop was issued, else the e-stop it latched
StopFor = Callable[[str], Awaitable["EStopEvent | None"]]

#: force monitor findings about the contact itself; the others say the wrench is not usable
CONTACT_KINDS = ("force_limit", "torque_limit", "joint_torque_limit")
#: the e-stop source of a wrench that could not be used (no force was measured: not "force_monitor")
WRENCH_LOST_SOURCE = "wrench_lost"
NO_WRENCH_MESSAGE = (
    "this backend provides no wrench estimate, so the contact force limit cannot be enforced, and the "
    "policy requires it (force.require_wrench: true); nothing was moved"
)


def contact_source(policy: Policy, backend: Backend) -> ContactSource | None:
    """What the force monitor reads for `policy` on `backend` (None: nothing; see `choose_contact_source`).
    Not the joint torques when the observer could integrate none of them (`unintegrable_joint_states`):
    every reading would be a lost one, so the plan, the approval and the refusal say so up front."""
    capabilities = backend.capabilities
    measures_torques = capabilities.joint_torques and _unintegrable(backend) is None
    return choose_contact_source(policy.force.source, capabilities.wrench, measures_torques,
                                 policy.force.joint_torques is not None)


def _unintegrable(backend: Backend) -> str | None:
    capabilities = backend.capabilities
    return unintegrable_joint_states(capabilities.joint_state_interval_s, capabilities.time_scale)


def no_contact_message(policy: Policy, backend: Backend) -> str:
    """Why no contact can be monitored on `backend`, for the NO_WRENCH refusal."""
    force, capabilities = policy.force, backend.capabilities
    if force.source == "sensor" or (not capabilities.joint_torques and force.joint_torques is None):
        return NO_WRENCH_MESSAGE
    problem = _unintegrable(backend) if capabilities.joint_torques else None
    if not capabilities.joint_torques:
        missing = f"backend {backend.name} measures no joint torques"
    elif problem is not None and force.joint_torques is not None:
        missing = problem
    else:
        missing = "the policy sets no external joint-torque limits (force.joint_torques)"
    return (f"{missing}, so contact cannot be monitored (force.source: {force.source}), and the policy requires it "
            "(force.require_wrench: true); nothing was moved")


@dataclass
class Execution:
    """The occupant of the Guard's execution slot: which plan, how far, since when."""

    plan_id: str
    progress: float = 0.0
    #: clock time the trajectory was handed to the backend; None until the arm may move
    started: float | None = None
    #: the backend's stop epoch when the slot was claimed: any stop after it, from any thread,
    #: keeps this trajectory from starting (see `Backend.execute`)
    stop_epoch: int | None = None


class MotionRunner:
    """Arms the force monitor, then runs a trajectory to its end, a stop or an e-stop."""

    def __init__(self, backend: Backend, policy: Policy, latch: EStopLatch, *, clock: Callable[[], float], audit: Any,
                 emergency_stop: EStop, stop_for: StopFor, record: Callable[[ExecutionReport], ExecutionReport],
                 robot: RobotModel | None = None) -> None:
        self.backend = backend
        self.latch = latch
        self.policy = policy
        #: the loaded robot model the joint-torque observer copies (None: no observer can be built)
        self.robot = robot
        self.require_wrench = policy.force.require_wrench
        self.audit = audit
        self._clock = clock
        self._emergency_stop = emergency_stop
        self._stop_for = stop_for
        self._record = record
        #: force/torque thresholds carried between executions while resting above a limit (see force.py)
        self._contact_ceiling: tuple[float | None, float | None] = (None, None)
        self._joint_ceiling: tuple[float | None, ...] | None = None

    # ------------------------------------------------------------------ before moving
    def force_limits(self, source: ContactSource) -> ForceLimits:
        """What the monitor holds a reading from `source` to (an estimated force has its own limit)."""
        return ForceLimits.from_policy(self.policy, source)

    def _reader(self, source: ContactSource) -> Callable[[], Awaitable[Any]]:
        """The monitor's read: the sensor's wrench, or a fresh observer over the joint states."""
        if source == "sensor":
            return self.backend.read_wrench
        if self.robot is None:
            raise SafetyRefusal(RefusalCode.NO_WRENCH, "contact from joint torques needs the robot model, and this "
                                "Guard was built without one; nothing was moved")
        observer = observer_for(self.policy, self.robot)  # one per execution: no state carried across motions
        return JointTorqueContact(self.backend.read_joint_states_since, observer, self.policy.robot.joint_names,
                                  self.backend.capabilities.time_scale, self.policy.force.wrench_timeout_s).read

    async def force_monitor(self) -> ForceMonitor | None:
        """A monitor with a fresh baseline, or None when the policy allows moving without one."""
        source = contact_source(self.policy, self.backend)
        if source is None:
            if self.require_wrench:
                raise SafetyRefusal(RefusalCode.NO_WRENCH, no_contact_message(self.policy, self.backend))
            return None
        monitor = ForceMonitor(self.force_limits(source), self._reader(source), clock=self._clock,
                               carried_ceiling=self._contact_ceiling, carried_joint_ceiling=self._joint_ceiling)
        baseline = await monitor.baseline()
        if isinstance(baseline, ForceViolation):
            raise SafetyRefusal(RefusalCode.NO_WRENCH, f"the wrench estimate cannot be used right now ({baseline.detail}); "
                                "refusing to move")
        if monitor.baseline_excessive:
            raise SafetyRefusal(RefusalCode.IN_CONTACT, f"the arm already presses with {_pressing(monitor)}, more than "
                                "twice the limit; a human must relieve the contact before anything moves")
        self._contact_ceiling = monitor.contact_ceiling  # kept until a baseline is back under the limit
        self._joint_ceiling = monitor.joint_contact_ceiling
        return monitor

    async def audit_start(self, plan: StoredPlan, approval: Approval) -> None:
        """`execution_started` on disk, or no motion."""
        if self.audit is None:
            return
        try:
            await self.audit.append_async(
                "execution_started", tool="execute_plan", arguments={"plan_id": plan.plan_id}, outcome="starting",
                operator=approval.operator, detail=f"{plan.trajectory.duration_s:.2f} s, approval via {approval.via}",
            )
        except Exception as exc:
            raise SafetyRefusal(RefusalCode.AUDIT_UNAVAILABLE, f"execute_plan refused: the audit log cannot be "
                                f"written ({exc}); nothing moved") from exc

    # ------------------------------------------------------------------ moving
    async def run(self, plan: StoredPlan, execution: Execution, approval: Approval,
                  monitor: ForceMonitor | None, report_progress: ProgressReporter | None) -> ExecutionReport:
        violation: ForceViolation | None = None
        result: ExecutionResult | None = None
        execution.started = self._clock()

        def on_progress(fraction: float) -> None:
            execution.progress = fraction

        async def on_violation(found: ForceViolation) -> None:
            nonlocal violation, fault
            violation = found
            if found.kind in CONTACT_KINDS:
                await self._emergency_stop(f"force monitor: {found.detail}", source="force_monitor", force=found.to_dict())
                return
            # no usable wrench: latch now, so nothing else actuates while the backend is asked why
            await self._emergency_stop(f"the wrench stream was lost ({found.detail}); checking whether the backend "
                                       "failed", source=WRENCH_LOST_SOURCE)
            cause = await self._diagnose_wrench_loss(plan.plan_id, found, self.latch.current_event)
            if cause is not None:  # report the cause (BACKEND_FAULT below), not the symptom
                fault = BackendError(f"{cause} (the force monitor saw: {found.detail})")

        async def forward_progress() -> None:
            sent = -1.0
            while True:
                await anyio.sleep(0.1)
                if report_progress is not None and execution.progress != sent:
                    sent = execution.progress
                    await report_progress(sent)

        fault: BackendError | None = None
        try:
            async with anyio.create_task_group() as group:
                if monitor is not None:
                    async def watch() -> None:
                        await monitor.run(on_violation)
                        group.cancel_scope.cancel()
                    group.start_soon(watch)
                group.start_soon(forward_progress)
                try:
                    result = await self.backend.execute(plan.trajectory, on_progress, stop_epoch=execution.stop_epoch)
                except BackendError as exc:  # caught here: out of the task group it would be an ExceptionGroup
                    fault = exc
                group.cancel_scope.cancel()
            # one more sample now that the motion ended: a crossing after the last poll still counts
            if (monitor is not None and violation is None and fault is None
                    and (final := await monitor.check_once()) is not None):
                with anyio.CancelScope(shield=True):
                    await on_violation(final)
        except anyio.get_cancelled_exc_class():
            with anyio.CancelScope(shield=True):
                await self._stop_after_interruption(plan.plan_id, execution, approval)
            raise
        if fault is not None:
            with anyio.CancelScope(shield=True):
                await self._emergency_stop(f"backend fault during execution: {fault}", source="backend_fault")
            raise SafetyRefusal(RefusalCode.BACKEND_FAULT, f"the backend failed during execution ({fault}); the e-stop "
                                "is latched, a human must inspect the robot and approve reset_estop") from fault
        duration = self._clock() - execution.started
        max_force = None if monitor is None else monitor.max_observed_force_n
        peaks = None if monitor is None else monitor.max_observed_external_torques_nm
        max_torques = None if peaks is None else [round(float(t), 4) for t in peaks]
        if violation is not None:
            self._record(ExecutionReport(
                plan_id=plan.plan_id, status="aborted", approval=approval.info(), duration_s=duration,
                max_observed_force_n=max_force, max_external_torques_nm=max_torques,
                detail=f"force monitor: {violation.detail}",
            ))
            event = self.latch.current_event
            what = violation.detail if violation.kind in CONTACT_KINDS else (
                f"the wrench stream was lost ({violation.detail}), so the contact force limit could not be "
                "enforced; the backend found no fault of its own")
            raise SafetyRefusal(
                RefusalCode.FORCE_LIMIT,
                f"motion aborted: {what}. The arm was stopped and the software e-stop "
                f"#{event.number if event else '?'} is latched; a human must check the robot and approve "
                "reset_estop before anything can move again.",
            )
        completed = result is not None and result.completed
        report = ExecutionReport(
            plan_id=plan.plan_id,
            status="succeeded" if completed else "aborted",
            approval=approval.info(),
            duration_s=duration,
            max_observed_force_n=max_force,
            max_external_torques_nm=max_torques,
            final_joint_error_rad=None if result is None else _largest_error(result.final_positions, plan.trajectory.goal),
            max_tracking_error_rad=None if result is None else result.max_tracking_error_rad,
            detail=("completed" if completed else f"stopped before the goal: {result.reason if result else 'no result'}")
            + ("" if monitor is not None else "; no wrench estimate: the contact force limit was NOT enforced"),
        )
        execution.progress = 1.0 if completed else execution.progress
        return self._record(report)

    async def _diagnose_wrench_loss(self, plan_id: str, found: ForceViolation, event: EStopEvent | None) -> str | None:
        """With the e-stop (`event`) latched for a lost wrench: ask the backend whether it is the
        cause, and audit the finding. Returns the backend's fault, or None when the wrench stream
        alone was lost. A backend that cannot answer is taken for a failed one (fail closed)."""
        try:
            cause = await self.backend.fault_behind_stale_data()
        except Exception as exc:
            cause = f"backend {self.backend.name} could not tell whether it failed ({type(exc).__name__}: {exc})"
        latched = f"e-stop #{event.number}" if event is not None else "the e-stop"
        if cause is not None:
            outcome, detail = "backend_fault", f"the backend failed: {cause}"
        else:
            outcome, detail = "wrench_only", "the backend found no fault of its own: the wrench stream alone was lost"
        if self.audit is not None:
            try:
                await self.audit.append_async(
                    "wrench_loss_diagnosis", tool="execute_plan", arguments={"plan_id": plan_id}, outcome=outcome,
                    detail=f"plan {plan_id}: the force monitor found no usable wrench ({found.detail}); {latched} "
                           f"latched at once; diagnosis: {detail}",
                    extra={"force_monitor": found.kind, "estop_event": None if event is None else event.number},
                )
            except Exception as exc:  # the e-stop holds, and the answer says the cause, recorded or not
                logger.critical("wrench loss diagnosis not audited (%s): plan %s: %s", exc, plan_id, detail)
        return cause

    async def _stop_after_interruption(self, plan_id: str, execution: Execution, approval: Approval) -> None:
        """The execute call was cancelled (client cancel, disconnect, timeout): stop, then record."""
        stop_failed = await self._stop_for("stop after an interrupted execution") is not None
        moved = 0.0 if execution.started is None else self._clock() - execution.started
        self._record(ExecutionReport(
            plan_id=plan_id, status="aborted", approval=approval.info(), duration_s=moved,
            max_observed_force_n=None, detail="interrupted: the call was cancelled",
        ))
        if self.audit is not None:
            outcome, what = ("stop_failed", "the stop FAILED (e-stop latched)") if stop_failed else ("stopped", "the arm was stopped")
            await self.audit.append_async("execution_interrupted", tool="execute_plan", outcome=outcome,
                                          detail=f"plan {plan_id}: the call was cancelled; {what}")


def _pressing(monitor: ForceMonitor) -> str:
    """The baseline contact, as the IN_CONTACT refusal names it."""
    baseline = monitor.baseline_wrench
    assert baseline is not None
    joints = getattr(baseline, "external_torques_nm", None)
    if joints is not None:
        return "external joint torques of " + ", ".join(f"{abs(float(t)):.1f}" for t in joints) + " N·m"
    return f"{baseline.force_norm_n:.1f} N / {baseline.torque_norm_nm:.2f} N·m"


def _largest_error(positions: np.ndarray, goal: np.ndarray) -> float | None:
    """max |positions − goal| [rad], or None when the backend's end position is unusable."""
    positions = np.asarray(positions, dtype=float)
    if positions.shape != goal.shape or not np.all(np.isfinite(positions)):
        return None
    return float(np.max(np.abs(positions - goal)))

