"""The Guard: the one door to the robot.

Every actuation (trajectory, gripper, controller switch, threshold change, error recovery) and
every backend read goes through a Guard method; the tool layer never touches the backend. The
Guard holds no check logic of its own: it owns the shared safety state (rate limiter, e-stop
latch, plan store, execution slot) and runs the components in order, refusing with a
`SafetyRefusal` at the first one that says no:

    rate limit → audit writable → e-stop latch → arguments (`safety.checks`) or the plan
    (`safety.plans`: exists, unexpired, this caller's, made since the last e-stop) → approval
    (`safety.approval`, prompts in `safety.prompts`) → re-validation (envelope now, arm still at
    the plan's start) → force monitor and audit record (`execution`) → no stop since → move

Its helpers each do one job: `readings` answers the read-only tools, `stopping` stops and
latches, `execution` runs one approved trajectory under the force monitor, `actions` describes
the control actions, `conversions` builds the results.

Concurrency model. The Guard lives on the event loop. Planning and envelope checks run on one
worker thread with their own Pinocchio data (`RuntimeModel`), so a long IK search never delays
a stop; state queries use a second, loop-side model. Stops never wait for anything but the
backend's stop (see `stopping`). An execution claims the slot synchronously and checks the stop
generation and the latch right before handing the trajectory over, so a stop that arrives during
its checks wins.

Approval resolvers call the `precheck_*` methods, which only read state (under protocol
2026-07-28 a resolver may run more than once per call); everything that changes state happens
in the action methods, which the tool body calls once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Literal

import anyio

from armwarden import conversions
from armwarden.actions import ControlAction, ControlTool, control_action
from armwarden.backends.base import Backend, Capabilities
from armwarden.callcontext import current_caller, note_approval
from armwarden.errors import RefusalCode, SafetyRefusal
from armwarden.execution import NO_WRENCH_MESSAGE, Execution, MotionRunner, ProgressReporter
from armwarden.policy import Policy
from armwarden.preflight import RuntimeModel
from armwarden.readings import MAX_STATE_AGE_S, Readings
from armwarden.results import (
    ActionResult,
    ControllerList,
    EnvelopeModel,
    EStopResult,
    ExecutionReport,
    GraphModel,
    GripperResultModel,
    MotionStatus,
    PlanSummary,
    ResetResult,
    RobotState,
    SafetyStatus,
    StopResult,
    TransformResult,
)
from armwarden.robot.model import RobotModel
from armwarden.safety import checks, prompts
from armwarden.safety.approval import Approval, Prompt, ServerDecision, approval_required, client_decision, interpret
from armwarden.safety.envelope import EnvelopeReport
from armwarden.safety.estop import EStopLatch
from armwarden.safety.plans import PlanRefusal, PlanStore
from armwarden.safety.ratelimit import RateLimiter
from armwarden.safety.violations import Violation
from armwarden.stopping import Stopper

PlanKind = Literal["joints", "pose", "cartesian"]
Previewer = Callable[[RuntimeModel, Any, EnvelopeReport], bytes | None]


def refuse(code: RefusalCode | str, message: str) -> SafetyRefusal:
    return SafetyRefusal(code, message)


class Guard:
    """The safety pipeline; see the module docstring."""

    def __init__(self, policy: Policy, planning: RuntimeModel, state_robot: RobotModel, backend: Backend, *,
                 audit=None, previewer: Previewer | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.policy = policy
        self.planning = planning
        self.robot = state_robot
        self.backend = backend
        self.audit = audit
        self._previewer = previewer
        self._clock = clock
        self.limiter = RateLimiter.from_policy(policy, clock=clock)
        self.latch = EStopLatch(clock=clock)
        self.plans = PlanStore.from_policy(policy, clock=clock)
        self.readings = Readings(policy, state_robot, backend, clock)
        self.stopper = Stopper(backend, self.latch, self.plans)
        self.faults = self.stopper.faults  # one list: stops, the audit writer and error recovery add to it
        self.runner = MotionRunner(backend, policy, self.latch, clock=clock, audit=audit,
                                   emergency_stop=self.stopper.emergency_stop, stop_for=self.stopper.stop_for,
                                   record=self._record)
        self._planning_slot = anyio.CapacityLimiter(1)  # one planning thread, one Pinocchio Data
        self._execution: Execution | None = None
        self._gripper_busy = False
        self._actions_done: dict[str, int] = {}  # completed approvable actions per tool (see action_round)
        self.last_violation: Violation | None = None
        self.last_result: ExecutionReport | None = None

    # ================================================================== admission
    @property
    def dry_run(self) -> bool:
        return self.policy.dry_run

    @property
    def capabilities(self) -> Capabilities:
        return self.backend.capabilities

    def admit(self, tool: str) -> None:
        """Rate limit (exempt tools always pass). Raises RATE_LIMITED."""
        decision = self.limiter.try_acquire(tool)
        if not decision.allowed:
            raise refuse(RefusalCode.RATE_LIMITED, decision.message)

    def charge(self, tool: str) -> None:
        """Take a rate token for a call refused before its body ran (bad arguments): floods of
        invalid calls still cost tokens."""
        self.limiter.try_acquire(tool)

    def _peek_rate(self, tool: str) -> ServerDecision | None:
        decision = self.limiter.peek(tool)
        return None if decision.allowed else ServerDecision.refused(RefusalCode.RATE_LIMITED, decision.message)

    def _estop_refusal(self, what: str) -> SafetyRefusal | None:
        event = self.latch.current_event
        if event is None:
            return None
        return refuse(RefusalCode.ESTOPPED, f"{what} refused: the software e-stop #{event.number} is latched "
                      f"({event.source}: {event.reason}). A human must approve reset_estop before anything can move again.")

    def require_audit(self, what: str) -> None:
        """Nothing actuates unless it can be audited: a log that failed a write refuses, and so do we."""
        if self.audit is not None and (self.audit.closed or self.audit.broken is not None):
            raise refuse(RefusalCode.AUDIT_UNAVAILABLE, f"{what} refused: the audit log cannot be written "
                         f"({self.audit.broken or 'closed'}); nothing moves until it is repaired and the daemon restarted")

    def require_not_estopped(self, what: str) -> None:
        if (refusal := self._estop_refusal(what)) is not None:
            raise refusal

    # ================================================================== introspection (reads only, see readings.py)
    async def robot_state(self) -> RobotState:
        return await self.readings.robot_state()

    def safety_envelope(self, registered_tools: list[str]) -> EnvelopeModel:
        return self.readings.safety_envelope(registered_tools)

    async def lookup_transform(self, target_frame: str, source_frame: str) -> TransformResult:
        return await self.readings.lookup_transform(target_frame, source_frame)

    async def list_controllers(self) -> ControllerList:
        return await self.readings.list_controllers()

    async def graph(self) -> GraphModel:
        return await self.readings.graph()

    async def camera(self, camera: str) -> tuple[int, int, float, bytes]:
        return await self.readings.camera(camera)

    def motion_status(self) -> MotionStatus:
        execution = self._execution
        return MotionStatus(
            executing=execution is not None,
            plan_id=None if execution is None else execution.plan_id,
            progress=0.0 if execution is None else min(1.0, max(0.0, execution.progress)),
            last_result=self.last_result,
        )

    def safety_status(self) -> SafetyStatus:
        return SafetyStatus(
            estopped=self.latch.is_latched,
            estop_event=conversions.estop_info(self.latch.current_event or self.latch.last_event),
            force_violation_latched=self.force_violation_latched and self.latch.is_latched,
            dry_run=self.dry_run,
            last_violation=None if self.last_violation is None else conversions.violation_model(self.last_violation),
            faults=list(self.faults),
        )

    # ================================================================== planning
    async def _run_planning(self, fn: Callable[[], Any]) -> Any:
        """Run `fn` on the planning thread (its own Pinocchio data); one at a time."""
        return await anyio.to_thread.run_sync(fn, limiter=self._planning_slot)

    async def plan(self, kind: PlanKind, request: dict[str, Any]) -> tuple[PlanSummary, bytes | None]:
        """Plan and check a motion (never moves); the plan belongs to the caller. Returns the
        summary and an optional preview PNG."""
        self.require_not_estopped("planning")
        generation = self.latch.generation  # an e-stop while planning voids the result
        start = (await self.readings.joint_state()).positions.copy()
        planner, envelope, previewer = self.planning.planner, self.planning.envelope, self._previewer
        vel, acc = request.get("velocity_scaling"), request.get("acceleration_scaling")

        def work() -> tuple[Any, EnvelopeReport | None, bytes | None]:
            if kind == "joints":
                outcome = planner.plan_to_joints(start, request["joint_positions"], vel, acc)
            elif kind == "pose":
                outcome = planner.plan_to_pose(start, request["target"], vel, acc)
            else:
                outcome = planner.plan_cartesian_path(start, request["waypoints"], vel, acc)
            if outcome.trajectory is None:
                return outcome, None, None
            report = envelope.check(outcome.trajectory)
            wants_preview = request.get("preview", True) and previewer is not None
            preview = previewer(self.planning, outcome.trajectory, report) if wants_preview and previewer else None
            return outcome, report, preview

        outcome, report, preview = await self._run_planning(work)
        if self.latch.generation != generation:
            raise refuse(RefusalCode.ESTOPPED, "an e-stop latched while this motion was being planned; the plan was "
                         "discarded. A human must approve reset_estop before anything can move again.")
        violations = list(outcome.violations) + (list(report.violations) if report else [])
        hard = [v for v in violations if v.is_hard]
        if violations:
            self.last_violation = hard[0] if hard else violations[0]
        monitoring = self.backend.capabilities.wrench
        notes = conversions.plan_notes(outcome.notes, monitoring, self.policy.force.require_wrench, self.dry_run)
        if outcome.trajectory is None or report is None:
            return conversions.plan_summary(violations, notes, monitoring), preview
        needs = not hard and approval_required(self.policy, "execute", any(not v.is_hard for v in violations))
        status = "rejected" if hard else ("needs_approval" if needs else "ok")
        stored = self.plans.add(outcome.trajectory, report, status=status, estop_generation=generation,
                                owner=current_caller(),
                                meta={"kind": kind, "notes": tuple(notes), "velocity_scaling": outcome.velocity_scaling})
        return conversions.plan_summary(
            violations, notes, monitoring, report=report, plan_id=stored.plan_id, status=status, requires_approval=needs,
            duration_s=outcome.trajectory.duration_s, expires_at=stored.expires_at_wall), preview

    # ================================================================== execution
    async def precheck_execute(self, plan_id: object, can_elicit: bool) -> ServerDecision | Prompt:
        """Everything that would refuse execute_plan, checked before any human is asked. Read-only."""
        if (d := self._peek_rate("execute_plan")) is not None:
            return d
        if (r := self._estop_refusal("execute_plan")) is not None:
            return ServerDecision.refusal(r)
        if self._execution is not None:
            return ServerDecision.refused(RefusalCode.BUSY, f"plan {self._execution.plan_id} is still executing")
        plan = self.plans.peek(plan_id, self.latch.generation, current_caller())
        if isinstance(plan, PlanRefusal):
            return ServerDecision.refused(plan.code, plan.message)
        try:
            state = await self.readings.joint_state()
        except SafetyRefusal as exc:
            return ServerDecision.refusal(exc)
        if (stale := self.plans.check_start(plan, state.positions)) is not None:
            return ServerDecision.refused(stale.code, stale.message)
        if not self.backend.capabilities.wrench and self.policy.force.require_wrench:
            return ServerDecision.refused(RefusalCode.NO_WRENCH, NO_WRENCH_MESSAGE)
        required = approval_required(self.policy, "execute", bool(plan.report.soft))
        decision = client_decision(self.policy, "execute_plan", required, can_elicit)
        if decision is not None:
            return decision
        return prompts.execute_prompt(self.policy, plan, self.backend.name, self.backend.capabilities.wrench, self.dry_run)

    def _interpret(self, outcome: Any, required: bool) -> Approval:
        """The resolver's outcome as an Approval, noted on the call's audit record."""
        approval = interpret(outcome, required)
        note_approval(approval.granted, approval.via, approval.operator, type(outcome).__name__)
        return approval

    async def execute(self, plan_id: str, approval_outcome: Any, shown_digest: str | None,
                      report_progress: ProgressReporter | None = None) -> ExecutionReport:
        """Run a stored plan: the only way the arm moves. The tool layer has admitted the call (rate
        limit); the rest of the order is the module docstring's. Each check here re-checks, at the
        last moment, something that may have changed since planning or while a human decided."""
        self.require_audit("execute_plan")
        if self._execution is not None:
            raise refuse(RefusalCode.BUSY, f"plan {self._execution.plan_id} is still executing; the plan {plan_id} stays usable")
        execution = self._execution = Execution(plan_id=str(plan_id))  # claimed synchronously
        stop_generation = self.stopper.generation
        try:
            # from here on the plan is spent, whatever happens (unless it is not this caller's)
            plan = self.plans.consume(plan_id, self.latch.generation, current_caller())
            if isinstance(plan, PlanRefusal):
                raise refuse(plan.code, plan.message)
            approval = self._interpret(approval_outcome, approval_required(self.policy, "execute", bool(plan.report.soft)))
            if not approval.granted:
                raise approval.refusal(f"execute_plan {plan.plan_id}")
            if approval.via == "elicitation" and shown_digest != plan.digest:
                raise refuse(RefusalCode.APPROVAL_MISMATCH, "the approval was given for a different plan; nothing was done")
            self.require_not_estopped("execute_plan")
            recheck = await self._run_planning(lambda: self.planning.envelope.check(plan.trajectory))
            if recheck.hard:
                self.last_violation = recheck.hard[0]
                raise refuse(RefusalCode.ENVELOPE, f"re-validation failed: {recheck.hard[0].code.value}: {recheck.hard[0].detail}")
            state = await self.readings.joint_state()  # the arm may have moved while a human was deciding
            if (stale := self.plans.check_start(plan, state.positions)) is not None:
                raise refuse(stale.code, stale.message)
            monitor = await self.runner.force_monitor()
            if not self.dry_run:
                await self.runner.audit_start(plan, approval)
            if self.stopper.generation != stop_generation or self.latch.is_latched:
                raise refuse(RefusalCode.STOPPED, "a stop or e-stop arrived while the plan was being checked; nothing moved")
            if self.dry_run:
                return self._record(ExecutionReport(
                    plan_id=plan.plan_id, status="dry_run", approval=approval.info(), duration_s=0.0,
                    max_observed_force_n=None, detail="dry run: validated and approved, nothing moved"))
            return await self.runner.run(plan, execution, approval, monitor, report_progress)
        finally:
            if self._execution is execution:
                self._execution = None

    def _record(self, report: ExecutionReport) -> ExecutionReport:
        self.last_result = report
        return report

    async def abandoned_call(self, tool: str, arguments: dict[str, Any], request_id: Any, cancelled: bool | None,
                             principal: str | None = None) -> None:
        """An HTTP client went away before its motion call answered (`transport/abandoned.py`).

        `cancelled` True: the call was cancelled in its session and the cancellation path stopped
        whatever it moved. None: a sessionless (2026-07-28) call, which the SDK ends with its
        request. False: the cancellation could not be delivered; if that call's motion still runs
        (same plan id; the one gripper action), it is stopped here. Audited in every case."""
        outcome = {True: "cancelled", None: "ended_with_request", False: "nothing_running"}[cancelled]
        detail = f"the client of {tool} (request {str(request_id)[:64]}) went away before the answer"
        if cancelled is False:
            running = (self._execution is not None and self._execution.plan_id == arguments.get("plan_id")
                       if tool == "execute_plan" else self._gripper_busy)
            if running:
                event = await self.stopper.stop_for("stop after a client disconnected")
                if event is None:
                    outcome, detail = "stopped", detail + "; the cancellation failed, so the robot was stopped"
                else:
                    outcome, detail = "stop_failed", detail + f"; the stop FAILED, e-stop #{event.number} latched ({event.reason})"
        if self.audit is not None:
            await self.audit.append_async("client_disconnected", principal=principal, tool=tool, arguments=arguments,
                                          outcome=outcome, detail=detail)

    # ================================================================== stop and e-stop (see stopping.py)
    async def stop_motion(self) -> StopResult:
        """Stop arm and gripper now. Never rate limited, never needs approval."""
        return await self.stopper.stop_motion()

    async def emergency_stop(self, reason: object, source: str = "estop", force: dict | None = None) -> EStopResult:
        """Latch, invalidate every plan and stop arm and gripper. Accepts any reason."""
        return await self.stopper.emergency_stop(reason, source, force)

    @property
    def force_violation_latched(self) -> bool:
        return self.stopper.force_violation_latched

    def precheck_reset(self, can_elicit: bool) -> ServerDecision | Prompt:
        event = self.latch.current_event
        if event is None:
            return ServerDecision.refused(RefusalCode.NOT_ESTOPPED, "the e-stop is not latched; nothing to reset")
        decision = client_decision(self.policy, "reset_estop", True, can_elicit)
        return decision if decision is not None else prompts.reset_prompt(event)

    def reset_estop(self, approval_outcome: Any, shown_event: str | None) -> ResetResult:
        approval = self._interpret(approval_outcome, True)
        if not approval.granted:
            raise approval.refusal("reset_estop")
        current = self.latch.current_event
        try:
            shown = int(shown_event) if shown_event is not None else (current.number if current else -1)
        except ValueError:
            shown = -1
        result = self.latch.release(shown)
        if not result.released:
            raise refuse(RefusalCode.RESET_REFUSED, f"reset_estop refused: {result.message}")
        self.stopper.force_violation_latched = False
        return ResetResult(estopped=self.latch.is_latched, released_event=shown, detail=result.message)

    # ================================================================== control actions
    def _action(self, tool: ControlTool, arguments: dict[str, Any]) -> ControlAction:
        return control_action(tool, arguments, policy=self.policy, backend=self.backend, round_=self.action_round(tool),
                              faults=self.faults, dry_run=self.dry_run)

    def action_round(self, tool: str) -> str:
        """Part of every action's approval digest and prompt: it changes after each completed action
        of `tool` and with each e-stop, so an approval (or a replayed protocol round carrying one)
        never carries over to a later request, nor across an e-stop and its reset."""
        return f"{self.latch.generation}.{self._actions_done.get(tool, 0)}"

    def precheck_action(self, tool: ControlTool, can_elicit: bool, **arguments: Any) -> ServerDecision | Prompt:
        """Pre-check for switch_controllers, set_collision_thresholds, error_recovery. Read-only."""
        action = self._action(tool, arguments)
        try:  # never ask a human to approve a request that would be refused anyway
            action.check()
        except SafetyRefusal as exc:
            return ServerDecision.refusal(exc)
        if (d := self._peek_rate(tool)) is not None:
            return d
        if (r := self._estop_refusal(tool)) is not None:
            return ServerDecision.refusal(r)
        decision = client_decision(self.policy, tool, approval_required(self.policy, tool), can_elicit)
        return decision if decision is not None else action.prompt()

    async def run_action(self, tool: ControlTool, approval_outcome: Any, shown: str | None, **arguments: Any) -> ActionResult:
        action = self._action(tool, arguments)
        action.check()
        self.require_audit(tool)
        self.require_not_estopped(tool)
        approval = self._interpret(approval_outcome, approval_required(self.policy, tool))
        if not approval.granted:
            raise approval.refusal(tool)
        if approval.via == "elicitation" and shown != action.prompt().digest:
            raise refuse(RefusalCode.APPROVAL_MISMATCH, f"{tool}: the approval was given for a different request; nothing was done")
        self._actions_done[tool] = self._actions_done.get(tool, 0) + 1  # this approval is now spent
        if self.dry_run:
            return ActionResult(status="dry_run", approval=approval.info(), detail=f"dry run: {action.done} would be done; nothing changed")
        await self.readings.backend_call(tool.replace("_", " "), action.actuate())
        return ActionResult(status="succeeded", approval=approval.info(), detail=action.done)

    # ================================================================== gripper
    async def gripper(self, tool: str, width_m: float | None = None, force_n: float | None = None,
                      speed_mps: float | None = None, epsilon_inner_m: float = 0.005,
                      epsilon_outer_m: float = 0.005) -> GripperResultModel:
        self.require_audit(tool)
        self.require_not_estopped(tool)
        speed = checks.check_gripper(self.policy, width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)
        if self._gripper_busy:
            raise refuse(RefusalCode.BUSY, "another gripper action is running")
        if self.dry_run:
            return GripperResultModel(status="dry_run", width_m=None, is_grasped=None, detail="dry run: nothing moved")
        self._gripper_busy = True
        try:
            if tool == "gripper_move":
                call = self.backend.gripper_move(width_m, speed)
            elif tool == "gripper_grasp":
                call = self.backend.gripper_grasp(width_m, force_n, speed, epsilon_inner_m, epsilon_outer_m)
            else:
                call = self.backend.gripper_home()
            try:
                result = await self.readings.backend_call(tool.replace("_", " "), call)
            except anyio.get_cancelled_exc_class():
                with anyio.CancelScope(shield=True):
                    await self.stop_motion()
                raise
        finally:
            self._gripper_busy = False
        return GripperResultModel(
            status="succeeded" if result.success else "failed", width_m=result.width_m, is_grasped=result.is_grasped,
            detail=result.detail or ("done" if result.success else "the gripper action did not succeed"),
        )


__all__ = ["MAX_STATE_AGE_S", "Approval", "Guard", "Prompt", "refuse"]
