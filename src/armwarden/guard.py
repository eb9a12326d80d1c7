"""The Guard: the one door to the robot.

Every tool call becomes one Guard request; every actuation (trajectory, gripper, controller
switch, threshold change, error recovery) goes through a Guard method, and the backend is
reachable from nowhere else. The Guard contains no check logic of its own: it runs the safety
components in order and refuses with a `SafetyRefusal` (a stable code and a message that says
what a human must do) at the first one that says no:

    rate limiter → e-stop latch → validation (policy + envelope) → approval → execution slot

Concurrency model. The Guard lives on the event loop. Planning and envelope checks run on one
worker thread with their own Pinocchio data (`RuntimeModel`), so a long IK search never delays
a stop; state queries use a second, loop-side model. `stop()`/`estop()` never wait for anything
but the backend's stop: they bump the stop generation and latch synchronously, then await the
backend. An execution claims the slot synchronously and checks the stop generation and the
latch right before handing the trajectory over, so a stop that arrives during its checks wins.

Approval resolvers call the `precheck_*` methods, which only read state (under protocol
2026-07-28 a resolver may run more than once per call); everything that changes state happens
in the `execute_*`/action methods, which the tool body calls once.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal

import anyio
import numpy as np

from armwarden import conversions
from armwarden.callcontext import current_call
from armwarden.backends.base import Backend, ExecutionResult, JointState
from armwarden.errors import BackendError, SafetyRefusal
from armwarden.planning.planners import PlanOutcome
from armwarden.policy import Policy
from armwarden.preflight import RuntimeModel
from armwarden.results import (
    ActionResult,
    ApprovalInfo,
    ControllerList,
    ControllerModel,
    EnvelopeModel,
    EStopResult,
    ExecutionReport,
    GraphModel,
    GripperModel,
    GripperResultModel,
    MotionStatus,
    PlanSummary,
    ResetResult,
    RobotState,
    SafetyStatus,
    StopResult,
    TransformResult,
)
from armwarden.robot.model import Pose, RobotModel
from armwarden.safety.approval import ServerDecision, approval_code, approval_required, compose_prompt
from armwarden.safety.envelope import EnvelopeReport
from armwarden.safety.estop import EStopEvent, EStopLatch, flatten_reason
from armwarden.safety.force import ForceLimits, ForceMonitor, ForceViolation
from armwarden.safety.plans import PlanRefusal, PlanStore, StoredPlan
from armwarden.safety.ratelimit import RateLimiter
from armwarden.safety.violations import Violation

logger = logging.getLogger(__name__)

PlanKind = Literal["joints", "pose", "cartesian"]
ProgressReporter = Callable[[float], Awaitable[None]]
Previewer = Callable[[RuntimeModel, Any, EnvelopeReport], bytes | None]

#: how stale a joint state may be before planning/execution refuses it [s]
MAX_STATE_AGE_S = 0.5


@dataclass(frozen=True)
class Approval:
    """What the tool body learned about approval: who decided, and how."""

    granted: bool
    via: Literal["not_required", "elicitation", "no_elicitation_client", "dry_run"]
    required: bool
    operator: str | None = None
    refusal_code: str = ""
    refusal_message: str = ""

    def info(self) -> ApprovalInfo:
        return ApprovalInfo(required=self.required, operator=self.operator, via=self.via)


@dataclass(frozen=True)
class Prompt:
    """A question for a human, with the server facts it was built from."""

    message: str
    digest: str  # what the human approves: a plan digest or an e-stop event number, as text


@dataclass
class _Execution:
    plan_id: str
    progress: float = 0.0


def refuse(code: str, message: str) -> SafetyRefusal:
    return SafetyRefusal(code, message)


class Guard:
    """The safety pipeline; see the module docstring."""

    def __init__(
        self,
        policy: Policy,
        planning: RuntimeModel,
        state_robot: RobotModel,
        backend: Backend,
        *,
        audit=None,
        previewer: Previewer | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
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
        self.force_limits = ForceLimits.from_policy(policy)
        self._planning_slot = anyio.CapacityLimiter(1)  # one planning thread, one Pinocchio Data
        self._execution: _Execution | None = None
        self._gripper_busy = False
        self._actions_done: dict[str, int] = {}  # completed approvable actions per tool (see action_round)
        #: force/torque thresholds carried between executions while resting above a limit (see force.py)
        self._contact_ceiling: tuple[float | None, float | None] = (None, None)
        self._stop_generation = 0
        self.last_violation: Violation | None = None
        self.faults: list[str] = []
        self.last_result: ExecutionReport | None = None
        self.force_violation_latched = False

    # ================================================================== common pre-checks
    @property
    def dry_run(self) -> bool:
        return self.policy.dry_run

    def admit(self, tool: str) -> None:
        """Rate limit (exempt tools always pass). Raises RATE_LIMITED."""
        decision = self.limiter.try_acquire(tool)
        if not decision.allowed:
            raise refuse("RATE_LIMITED", decision.message)

    def _peek_rate(self, tool: str) -> ServerDecision | None:
        decision = self.limiter.peek(tool)
        return None if decision.allowed else ServerDecision(False, "refused", "RATE_LIMITED", decision.message)

    def _estop_refusal(self, what: str) -> SafetyRefusal | None:
        event = self.latch.current_event
        if event is None:
            return None
        return refuse(
            "ESTOPPED",
            f"{what} refused: the software e-stop #{event.number} is latched ({event.source}: {event.reason}). "
            "A human must approve reset_estop before anything can move again.",
        )

    def require_audit(self, what: str) -> None:
        """Nothing actuates unless it can be audited: a log that failed a write refuses, and so do we."""
        if self.audit is not None and (self.audit.closed or self.audit.broken is not None):
            raise refuse("AUDIT_UNAVAILABLE", f"{what} refused: the audit log cannot be written "
                         f"({self.audit.broken or 'closed'}); nothing moves until it is repaired and the daemon restarted")

    def require_not_estopped(self, what: str) -> None:
        refusal = self._estop_refusal(what)
        if refusal is not None:
            raise refusal

    async def _joint_state(self) -> JointState:
        try:
            state = await self.backend.read_joint_state()
        except (BackendError, TimeoutError) as exc:
            raise refuse("NO_STATE", f"cannot read the joint state from the backend: {exc}") from exc
        age = self._clock() - state.stamp
        if not np.all(np.isfinite(state.positions)) or age > MAX_STATE_AGE_S:
            raise refuse("STALE_STATE", f"the joint state is invalid or {age:.3f} s old; refusing to plan or move on it")
        return state

    # ================================================================== introspection
    async def robot_state(self) -> RobotState:
        state = await self._joint_state()
        pose = self.robot.tcp_pose(state.positions)
        try:
            wrench = await self.backend.read_wrench()
        except (BackendError, TimeoutError):
            wrench = None
        gripper = await self.backend.gripper_state() if self.backend.capabilities.gripper else None
        return RobotState(
            joint_names=list(self.robot.joint_names),
            joint_positions=[float(v) for v in state.positions],
            joint_velocities=[float(v) for v in state.velocities],
            tcp_pose=conversions.pose_model(pose),
            frame_id=self.robot.base_frame,
            wrench=conversions.wrench_model(wrench),
            gripper=None
            if gripper is None
            else GripperModel(width_m=gripper.width_m, is_grasped=gripper.is_grasped, moving=gripper.moving),
            stamp=state.stamp,
        )

    def safety_envelope(self, registered_tools: list[str]) -> EnvelopeModel:
        p = self.policy
        robot = p.robot
        ws = p.workspace
        return EnvelopeModel(
            robot=robot.name,
            base_frame=robot.base_frame,
            tcp_frame=robot.tcp_frame,
            joint_names=list(robot.joint_names),
            joint_limits={n: robot.joint_limits[n].model_dump() for n in robot.joint_names},
            workspace_box={"min": list(ws.box.min), "max": list(ws.box.max)},
            keep_out=[{"name": z.name, "min": list(z.min), "max": list(z.max)} for z in ws.keep_out],
            link_padding_m=ws.link_padding_m,
            checked_links=sorted({c.link for c in self.robot.capsules}),
            self_collision=ws.self_collision,
            motion=p.motion.model_dump(),
            force=p.force.model_dump(),
            gripper=None if p.gripper is None else p.gripper.model_dump(),
            controllers_allowlist=list(p.controllers.allowlist),
            cameras=list(p.perception.cameras),
            approval_mode=p.approval.mode,
            dry_run=self.dry_run,
            tools=registered_tools,
        )

    async def lookup_transform(self, target_frame: str, source_frame: str) -> TransformResult:
        frames = set(self.robot.frame_names())
        for name in (target_frame, source_frame):
            if name not in frames:
                shown = ", ".join(sorted(frames)[:40])
                raise refuse("UNKNOWN_FRAME", f"unknown frame {flatten_reason(name, 80)!r}; known frames: {shown}")
        q = (await self._joint_state()).positions
        target = self.robot.frame_pose(q, target_frame).as_se3()
        source = self.robot.frame_pose(q, source_frame).as_se3()
        relative = target.inverse() * source
        return TransformResult(
            target_frame=target_frame,
            source_frame=source_frame,
            pose=conversions.pose_model(Pose(relative.translation.copy(), relative.rotation.copy())),
        )

    async def list_controllers(self) -> ControllerList:
        allowed = set(self.policy.controllers.allowlist)
        controllers = await self._backend_call("list controllers", self.backend.list_controllers())
        return ControllerList(
            controllers=[ControllerModel(name=c.name, type=c.type, state=c.state, switchable=c.name in allowed) for c in controllers]
        )

    async def graph(self) -> GraphModel:
        graph = await self._backend_call("read the graph", self.backend.graph())
        return GraphModel(**{key: sorted(graph.get(key, [])) for key in ("nodes", "topics", "services", "actions")})

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

    async def _backend_call(self, what: str, awaitable: Awaitable[Any]) -> Any:
        try:
            return await awaitable
        except (BackendError, TimeoutError, NotImplementedError) as exc:
            raise refuse("BACKEND_ERROR", f"the backend could not {what}: {exc}") from exc

    # ================================================================== planning
    async def _run_planning(self, fn: Callable[[], Any]) -> Any:
        """Run `fn` on the planning thread (its own Pinocchio data); one at a time."""
        return await anyio.to_thread.run_sync(fn, limiter=self._planning_slot)

    async def plan(self, kind: PlanKind, request: dict[str, Any]) -> tuple[PlanSummary, bytes | None]:
        """Plan and check a motion (never moves). Returns the summary and an optional preview PNG."""
        self.require_not_estopped("planning")
        generation = self.latch.generation  # an e-stop while planning voids the result
        start = (await self._joint_state()).positions.copy()
        planner, envelope = self.planning.planner, self.planning.envelope
        vel, acc = request.get("velocity_scaling"), request.get("acceleration_scaling")

        def work() -> tuple[PlanOutcome, EnvelopeReport | None, bytes | None]:
            if kind == "joints":
                outcome = planner.plan_to_joints(start, request["joint_positions"], vel, acc)
            elif kind == "pose":
                outcome = planner.plan_to_pose(start, request["target"], vel, acc)
            else:
                outcome = planner.plan_cartesian_path(start, request["waypoints"], vel, acc)
            if outcome.trajectory is None:
                return outcome, None, None
            report = envelope.check(outcome.trajectory)
            wants_preview = request.get("preview", True) and self._previewer is not None
            preview = self._previewer(self.planning, outcome.trajectory, report) if wants_preview else None
            return outcome, report, preview

        outcome, report, preview = await self._run_planning(work)
        if self.latch.generation != generation:
            raise refuse("ESTOPPED", "an e-stop latched while this motion was being planned; the plan was discarded. "
                         "A human must approve reset_estop before anything can move again.")
        return self._summarize(kind, outcome, report, generation), preview

    def _summarize(self, kind: PlanKind, outcome: PlanOutcome, report: EnvelopeReport | None,
                   estop_generation: int) -> PlanSummary:
        violations = list(outcome.violations) + (list(report.violations) if report else [])
        notes = list(outcome.notes)
        hard = [v for v in violations if v.is_hard]
        if violations:
            self.last_violation = hard[0] if hard else violations[0]
        force_monitoring = self.backend.capabilities.wrench
        if not force_monitoring:
            notes.append(
                "no wrench estimate: the contact force limit is NOT enforced"
                if not self.policy.force.require_wrench
                else "no wrench estimate: execute_plan will refuse (force.require_wrench is true)"
            )
        if self.dry_run:
            notes.append("dry run: execute_plan will validate and ask, but nothing will move")
        if outcome.trajectory is None or report is None:
            return PlanSummary(
                plan_id=None, status="rejected", violations=[conversions.violation_model(v) for v in violations],
                requires_approval=False, duration_s=0.0, max_joint_velocity_ratio=0.0,
                max_joint_acceleration_ratio=0.0, max_joint_travel_rad=0.0, tcp_path_length_m=0.0,
                final_tcp_pose=None, force_monitoring=force_monitoring, expires_at=None, notes=notes,
            )
        soft = [v for v in violations if not v.is_hard]
        needs = not hard and approval_required(self.policy, "execute", bool(soft))
        status = "rejected" if hard else ("needs_approval" if needs else "ok")
        stored = self.plans.add(
            outcome.trajectory,
            report,
            status=status,
            estop_generation=estop_generation,
            meta={"kind": kind, "notes": tuple(notes), "velocity_scaling": outcome.velocity_scaling},
        )
        return PlanSummary(
            plan_id=stored.plan_id,
            status=status,
            violations=[conversions.violation_model(v) for v in violations],
            requires_approval=needs,
            duration_s=outcome.trajectory.duration_s,
            max_joint_velocity_ratio=report.max_joint_velocity_ratio,
            max_joint_acceleration_ratio=report.max_joint_acceleration_ratio,
            max_joint_travel_rad=report.max_joint_travel_rad,
            tcp_path_length_m=report.tcp_path_length_m,
            final_tcp_pose=None if report.final_tcp_pose is None else conversions.pose_model(report.final_tcp_pose),
            force_monitoring=force_monitoring,
            expires_at=stored.expires_at_wall,
            notes=notes,
        )

    # ================================================================== execution: pre-check (resolver side)
    def _client_decision(self, action: str, required: bool, can_elicit: bool) -> ServerDecision | None:
        """No prompt needed (proceed), cannot prompt (policy decides), or None: ask the human.
        Releasing the e-stop always needs a human, whatever `on_client_without_elicitation` says."""
        if not required:
            return ServerDecision(True, "not_required")
        if can_elicit:
            return None
        if self.policy.approval.on_client_without_elicitation == "allow" and action != "reset_estop":
            return ServerDecision(True, "no_elicitation_client")
        return ServerDecision(
            False,
            "refused",
            "APPROVAL_UNAVAILABLE",
            f"{action} needs a human's approval, but this MCP client cannot show approval prompts "
            "(no elicitation support) and the policy denies such requests. Use a client that supports "
            "elicitation.",
        )

    async def precheck_execute(self, plan_id: object, can_elicit: bool) -> ServerDecision | Prompt:
        """Everything that would refuse execute_plan, checked before any human is asked. Read-only."""
        if (d := self._peek_rate("execute_plan")) is not None:
            return d
        if (r := self._estop_refusal("execute_plan")) is not None:
            return ServerDecision.refusal(r)
        if self._execution is not None:
            return ServerDecision(False, "refused", "BUSY", f"plan {self._execution.plan_id} is still executing")
        plan = self.plans.peek(plan_id, self.latch.generation)
        if isinstance(plan, PlanRefusal):
            return ServerDecision(False, "refused", plan.code, plan.message)
        try:
            state = await self._joint_state()
        except SafetyRefusal as exc:
            return ServerDecision.refusal(exc)
        if (stale := self.plans.check_start(plan, state.positions)) is not None:
            return ServerDecision(False, "refused", stale.code, stale.message)
        if not self.backend.capabilities.wrench and self.policy.force.require_wrench:
            return ServerDecision(False, "refused", "NO_WRENCH", _NO_WRENCH_MESSAGE)
        required = approval_required(self.policy, "execute", bool(plan.report.soft))
        decision = self._client_decision("execute_plan", required, can_elicit)
        if decision is not None:
            return decision
        return Prompt(self._execute_prompt(plan), plan.digest)

    def _execute_prompt(self, plan: StoredPlan) -> str:
        report = plan.report
        motion = self.policy.motion
        final = report.final_tcp_pose
        facts = [
            ("Robot", f"{self.policy.robot.name} via the {self.backend.name} backend"),
            ("Approval code", approval_code(plan.digest)),
            ("Plan", plan.plan_id),
            ("Duration", f"{plan.trajectory.duration_s:.2f} s"),
            ("Peak joint speed", f"{report.max_joint_velocity_ratio:.0%} of limit (cap {motion.max_velocity_scaling:.0%})"),
            ("Largest joint travel", f"{report.max_joint_travel_rad:.3f} rad ({np.degrees(report.max_joint_travel_rad):.1f} deg)"),
            ("TCP path length", f"{report.tcp_path_length_m:.3f} m"),
        ]
        if final is not None:
            x, y, z = final.position
            facts.append(("Final TCP position", f"({x:.3f}, {y:.3f}, {z:.3f}) m in {self.policy.robot.base_frame}"))
        force = self.policy.force
        facts.append(
            ("Force monitoring", f"ON, stops above {force.max_contact_force_n:g} N / {force.max_contact_torque_nm:g} N·m")
            if self.backend.capabilities.wrench
            else ("Force monitoring", "OFF: the contact force limit is NOT enforced")
        )
        if self.dry_run:
            facts.append(("Dry run", "yes: nothing will move"))
        warnings = [f"{v.code.value}: {v.detail}" for v in report.soft]
        return compose_prompt("APPROVE ROBOT MOTION?", facts, warnings)

    # ================================================================== execution: the body
    def interpret(self, outcome: Any, required: bool) -> Approval:
        """Turn the resolver outcome (a ServerDecision or an elicitation result) into an Approval.

        The human's answer (and the name they gave) is noted on the call's audit record.
        """
        approval = self._interpret(outcome, required)
        record = current_call()
        if record is not None:
            record.operator = approval.operator or record.operator
            record.extra["approval"] = {"granted": approval.granted, "via": approval.via, "operator": approval.operator,
                                        "answer": type(outcome).__name__}
        return approval

    def _interpret(self, outcome: Any, required: bool) -> Approval:
        from mcp.server.mcpserver import AcceptedElicitation, CancelledElicitation, DeclinedElicitation

        from armwarden.safety.approval import ApprovalForm

        if isinstance(outcome, AcceptedElicitation):
            data = outcome.data
            if isinstance(data, ServerDecision):
                if data.proceed:
                    return Approval(True, data.via if data.via != "refused" else "not_required", required)
                return Approval(False, "not_required", required, None, data.code, data.message)
            if isinstance(data, ApprovalForm):
                operator = flatten_reason(data.operator, 64) if data.operator else None
                if data.approve is True:
                    return Approval(True, "elicitation", True, operator)
                return Approval(False, "elicitation", True, operator, "APPROVAL_DENIED",
                                "the human did not tick 'approve'; nothing was done")
        if isinstance(outcome, DeclinedElicitation):
            return Approval(False, "elicitation", True, None, "APPROVAL_DENIED", "the human declined; nothing was done")
        if isinstance(outcome, CancelledElicitation):
            return Approval(False, "elicitation", True, None, "APPROVAL_DENIED", "the human cancelled; nothing was done")
        return Approval(False, "not_required", required, None, "APPROVAL_INVALID", "unrecognised approval outcome; nothing was done")

    async def execute(self, plan_id: str, approval_outcome: Any, shown_digest: str | None,
                      report_progress: ProgressReporter | None = None) -> ExecutionReport:
        """Run a stored plan: the only way the arm moves. See the module docstring for the order."""
        self.admit("execute_plan")  # a refusal here leaves the plan usable
        self.require_audit("execute_plan")
        if self._execution is not None:
            raise refuse("BUSY", f"plan {self._execution.plan_id} is still executing; the plan {plan_id} stays usable")
        execution = self._execution = _Execution(plan_id=str(plan_id))  # claimed synchronously
        stop_generation = self._stop_generation
        try:
            plan = self.plans.consume(plan_id, self.latch.generation)  # from here on the plan is spent, whatever happens
            if isinstance(plan, PlanRefusal):
                raise refuse(plan.code, plan.message)
            required = approval_required(self.policy, "execute", bool(plan.report.soft))
            approval = self.interpret(approval_outcome, required)
            if not approval.granted:
                raise refuse(approval.refusal_code, f"execute_plan {plan.plan_id}: {approval.refusal_message}")
            if approval.via == "elicitation" and shown_digest != plan.digest:
                raise refuse("APPROVAL_MISMATCH", "the approval was given for a different plan; nothing was done")
            self.require_not_estopped("execute_plan")
            recheck = await self._run_planning(lambda: self.planning.envelope.check(plan.trajectory))
            if recheck.hard:
                self.last_violation = recheck.hard[0]
                raise refuse("ENVELOPE", f"re-validation failed: {recheck.hard[0].code.value}: {recheck.hard[0].detail}")
            state = await self._joint_state()
            if (stale := self.plans.check_start(plan, state.positions)) is not None:
                raise refuse(stale.code, stale.message)
            monitor = await self._force_monitor()
            if not self.dry_run:  # on disk before the arm moves: a crash mid-motion still leaves a trace
                await self._audit_start(plan, approval)
            if self._stop_generation != stop_generation or self.latch.is_latched:
                raise refuse("STOPPED", "a stop or e-stop arrived while the plan was being checked; nothing moved")
            if self.dry_run:
                return self._record(ExecutionReport(
                    plan_id=plan.plan_id, status="dry_run", approval=approval.info(), duration_s=0.0,
                    max_observed_force_n=None, detail="dry run: validated and approved, nothing moved",
                ))
            return await self._run(plan, execution, approval, monitor, report_progress)
        finally:
            if self._execution is execution:
                self._execution = None

    async def _audit_start(self, plan: StoredPlan, approval: Approval) -> None:
        if self.audit is None:
            return
        try:
            await self.audit.append_async(
                "execution_started", tool="execute_plan", arguments={"plan_id": plan.plan_id}, outcome="starting",
                operator=approval.operator, detail=f"{plan.trajectory.duration_s:.2f} s, approval via {approval.via}",
            )
        except Exception as exc:
            raise refuse("AUDIT_UNAVAILABLE", f"execute_plan refused: the audit log cannot be written ({exc}); "
                         "nothing moved") from exc

    async def _force_monitor(self) -> ForceMonitor | None:
        if not self.backend.capabilities.wrench:
            if self.policy.force.require_wrench:
                raise refuse("NO_WRENCH", _NO_WRENCH_MESSAGE)
            return None
        monitor = ForceMonitor(self.force_limits, self.backend.read_wrench, clock=self._clock,
                               carried_ceiling=self._contact_ceiling)
        if await monitor.baseline() is None:
            raise refuse("NO_WRENCH", "the wrench estimate is missing, slow, stale or invalid right now; refusing to move")
        if monitor.baseline_excessive:
            raise refuse("IN_CONTACT", f"the arm already presses with {monitor.baseline_wrench.force_norm_n:.1f} N / "
                         f"{monitor.baseline_wrench.torque_norm_nm:.2f} N·m, more than twice the limit; a human must "
                         "relieve the contact before anything moves")
        self._contact_ceiling = monitor.contact_ceiling  # kept until a baseline is back under the limit
        return monitor

    async def _run(self, plan: StoredPlan, execution: _Execution, approval: Approval,
                   monitor: ForceMonitor | None, report_progress: ProgressReporter | None) -> ExecutionReport:
        violation: ForceViolation | None = None
        result: ExecutionResult | None = None
        started = self._clock()

        def on_progress(fraction: float) -> None:
            execution.progress = fraction

        async def on_violation(found: ForceViolation) -> None:
            nonlocal violation
            violation = found
            await self.emergency_stop(f"force monitor: {found.detail}", source="force_monitor", force=found.to_dict())

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
                    result = await self.backend.execute(plan.trajectory, on_progress)
                except BackendError as exc:  # caught here: out of the task group it would be an ExceptionGroup
                    fault = exc
                group.cancel_scope.cancel()
            if monitor is not None and violation is None and fault is None:
                # one more sample now that the motion ended: a crossing after the last poll still counts
                if (final := await monitor.check_once()) is not None:
                    with anyio.CancelScope(shield=True):
                        await on_violation(final)
        except anyio.get_cancelled_exc_class():
            with anyio.CancelScope(shield=True):
                await self._stop_after_interruption(plan.plan_id)
            raise
        if fault is not None:
            with anyio.CancelScope(shield=True):
                await self.emergency_stop(f"backend fault during execution: {fault}", source="backend_fault")
            raise refuse("BACKEND_FAULT", f"the backend failed during execution ({fault}); the e-stop is latched, "
                         "a human must inspect the robot and approve reset_estop") from fault
        duration = self._clock() - started
        max_force = None if monitor is None else monitor.max_observed_force_n
        if violation is not None:
            report = ExecutionReport(
                plan_id=plan.plan_id, status="aborted", approval=approval.info(), duration_s=duration,
                max_observed_force_n=max_force, detail=f"force monitor: {violation.detail}",
            )
            self._record(report)
            raise refuse(
                "FORCE_LIMIT",
                f"motion aborted: {violation.detail}. The arm was stopped and the software e-stop "
                f"#{self.latch.current_event.number if self.latch.current_event else '?'} is latched; a human must "
                "check the robot and approve reset_estop before anything can move again.",
            )
        completed = result is not None and result.completed
        report = ExecutionReport(
            plan_id=plan.plan_id,
            status="succeeded" if completed else "aborted",
            approval=approval.info(),
            duration_s=duration,
            max_observed_force_n=max_force,
            detail=("completed" if completed else f"stopped before the goal: {result.reason}")
            + ("" if monitor is not None else "; no wrench estimate: the contact force limit was NOT enforced"),
        )
        execution.progress = 1.0 if completed else execution.progress
        return self._record(report)

    def _record(self, report: ExecutionReport) -> ExecutionReport:
        self.last_result = report
        return report

    async def _stop_after_interruption(self, plan_id: str) -> None:
        """The execute call was cancelled (client cancel, disconnect, timeout): stop, then record."""
        stop_failed = await self._stop_for("stop after an interrupted execution") is not None
        self.last_result = ExecutionReport(
            plan_id=plan_id, status="aborted", approval=ApprovalInfo(required=False, operator=None, via="not_required"),
            duration_s=0.0, max_observed_force_n=None, detail="interrupted: the call was cancelled",
        )
        if self.audit is not None:
            outcome, what = ("stop_failed", "the stop FAILED (e-stop latched)") if stop_failed else ("stopped", "the arm was stopped")
            await self.audit.append_async("execution_interrupted", tool="execute_plan", outcome=outcome,
                                          detail=f"plan {plan_id}: the call was cancelled; {what}")

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
                event = await self._stop_for("stop after a client disconnected")
                if event is None:
                    outcome, detail = "stopped", detail + "; the cancellation failed, so the robot was stopped"
                else:
                    outcome, detail = "stop_failed", detail + f"; the stop FAILED, e-stop #{event.number} latched ({event.reason})"
        if self.audit is not None:
            await self.audit.append_async("client_disconnected", principal=principal, tool=tool, arguments=arguments,
                                          outcome=outcome, detail=detail)

    # ================================================================== stop and e-stop
    async def stop_motion(self) -> StopResult:
        """Stop arm and gripper now. Never rate limited, never needs approval."""
        self._stop_generation += 1
        try:
            await self._timed_stop()
        except BackendError as exc:
            event = self._latch_failed_stop("stop_motion", exc)
            raise refuse("STOP_FAILED", f"the stop command failed ({exc}); the software e-stop #{event.number} is "
                         "latched. Use the hardware e-stop if the robot is still moving.") from exc
        return StopResult(stopped=True, detail="stop commanded for arm and gripper")

    async def emergency_stop(self, reason: object, source: str = "estop", force: dict | None = None) -> EStopResult:
        """Latch, invalidate every plan and stop arm and gripper. Accepts any reason."""
        self._stop_generation += 1
        event = self.latch.latch(reason, source, force_violation=force)
        if source == "force_monitor":
            self.force_violation_latched = True
        self.plans.invalidate_all(f"e-stop #{event.number}")
        try:
            await self._timed_stop()
        except BackendError as exc:
            self.faults.append(f"stop during e-stop #{event.number} failed: {exc}")
            event = self.latch.latch(f"stop failed during e-stop #{event.number}: {exc}", "stop_failed")
        return EStopResult(estopped=True, estop_event=conversions.estop_info(event))

    async def _stop_for(self, what: str) -> EStopEvent | None:
        """Stop arm and gripper for a call that can no longer do it itself (cancelled, abandoned).
        Returns None when the stop was issued, else the e-stop event latched because it failed."""
        self._stop_generation += 1
        try:
            await self.backend.stop()
        except BackendError as exc:
            return self._latch_failed_stop(what, exc)
        return None

    def _latch_failed_stop(self, what: str, exc: BaseException) -> EStopEvent:
        """A stop that could not be issued: latch the e-stop, void every plan, report the fault."""
        event = self.latch.latch(f"{what} failed: {exc}", "stop_failed")
        self.plans.invalidate_all("stop failed")
        self.faults.append(f"{what} failed: {exc}")
        return event

    async def _timed_stop(self) -> None:
        """The backend stop, with when it was issued and confirmed noted on the call's audit record."""
        issued = time.monotonic()
        stopped = False
        try:
            await self.backend.stop()
            stopped = True
        finally:
            record = current_call()
            if record is not None:
                timing = {
                    "issued_after_receipt": round((issued - record.received_mono) * 1e3, 4),
                    "confirmed_after_receipt": round((time.monotonic() - record.received_mono) * 1e3, 4),
                }
                still = self.backend.last_stop_stamp
                if stopped and isinstance(still, float) and still >= issued:  # this stop's, and it worked
                    timing["still_after_receipt"] = round((still - record.received_mono) * 1e3, 4)
                record.extra["stop_timing_ms"] = timing

    def precheck_reset(self, can_elicit: bool) -> ServerDecision | Prompt:
        event = self.latch.current_event
        if event is None:
            return ServerDecision(False, "refused", "NOT_ESTOPPED", "the e-stop is not latched; nothing to reset")
        decision = self._client_decision("reset_estop", True, can_elicit)
        if decision is not None:
            return decision
        facts = [
            ("E-stop event", f"#{event.number}"),
            ("Latched at", conversions.iso_utc(event.wall_time)),
            ("Source", event.source),
        ]
        if event.force_violation:
            facts.append(("Force violation", flatten_reason(event.force_violation.get("detail", ""), 200)))
        prompt = compose_prompt(
            "RELEASE THE SOFTWARE E-STOP?",
            facts,
            ["Releasing lets the agent plan and move again. Check the robot and its surroundings first."],
            untrusted=event.reason if event.source == "estop" else None,
        )
        return Prompt(prompt, str(event.number))

    def reset_estop(self, approval_outcome: Any, shown_event: str | None) -> ResetResult:
        approval = self.interpret(approval_outcome, True)
        if not approval.granted:
            raise refuse(approval.refusal_code, f"reset_estop: {approval.refusal_message}")
        current = self.latch.current_event
        try:
            shown = int(shown_event) if shown_event is not None else (current.number if current else -1)
        except ValueError:
            shown = -1
        result = self.latch.release(shown)
        if not result.released:
            raise refuse("RESET_REFUSED", f"reset_estop refused: {result.message}")
        self.force_violation_latched = False
        return ResetResult(estopped=self.latch.is_latched, released_event=shown, detail=result.message)

    # ================================================================== other actions
    def precheck_action(self, action: str, tool: str, can_elicit: bool, describe: Callable[[], Prompt]) -> ServerDecision | Prompt:
        """Pre-check for switch_controllers, set_collision_thresholds, error_recovery."""
        if (d := self._peek_rate(tool)) is not None:
            return d
        if (r := self._estop_refusal(tool)) is not None:
            return ServerDecision.refusal(r)
        required = approval_required(self.policy, action)  # type: ignore[arg-type]
        decision = self._client_decision(tool, required, can_elicit)
        return decision if decision is not None else describe()

    def action_round(self, tool: str) -> str:
        """Part of every action's approval digest and prompt: it changes after each completed action
        of `tool` and with each e-stop, so an approval (or a replayed protocol round carrying one)
        never carries over to a later request, nor across an e-stop and its reset."""
        return f"{self.latch.generation}.{self._actions_done.get(tool, 0)}"

    async def run_action(self, action: str, tool: str, approval_outcome: Any, shown: str | None, expected: str,
                         actuate: Callable[[], Awaitable[None]], done: str) -> ActionResult:
        self.admit(tool)
        self.require_audit(tool)
        self.require_not_estopped(tool)
        approval = self.interpret(approval_outcome, approval_required(self.policy, action))  # type: ignore[arg-type]
        if not approval.granted:
            raise refuse(approval.refusal_code, f"{tool}: {approval.refusal_message}")
        if approval.via == "elicitation" and shown != expected:
            raise refuse("APPROVAL_MISMATCH", f"{tool}: the approval was given for a different request; nothing was done")
        self._actions_done[tool] = self._actions_done.get(tool, 0) + 1  # this approval is now spent
        if self.dry_run:
            return ActionResult(status="dry_run", approval=approval.info(), detail=f"dry run: {done} would be done; nothing changed")
        await self._backend_call(tool.replace("_", " "), actuate())
        return ActionResult(status="succeeded", approval=approval.info(), detail=done)

    def check_controllers(self, activate: list[str], deactivate: list[str]) -> None:
        allowed = set(self.policy.controllers.allowlist)
        outside = [c for c in [*activate, *deactivate] if c not in allowed]
        if outside:
            raise refuse("NOT_ALLOWED", f"controller(s) {[flatten_reason(c, 64) for c in outside]} are not in the policy's "
                         f"allowlist {sorted(allowed)}")
        if not activate and not deactivate:
            raise refuse("INVALID", "nothing to switch: give activate and/or deactivate")

    def check_thresholds(self, force_n: float, torque_nm: float) -> None:
        force = self.policy.force
        if not (0.0 < force_n <= force.max_contact_force_n):
            raise refuse("OUT_OF_RANGE", f"force_n {force_n:g} N must be in (0, {force.max_contact_force_n:g}] N")
        if not (0.0 < torque_nm <= force.max_contact_torque_nm):
            raise refuse("OUT_OF_RANGE", f"torque_nm {torque_nm:g} N·m must be in (0, {force.max_contact_torque_nm:g}] N·m")

    async def error_recovery_actuate(self) -> None:
        await self.backend.error_recovery()
        self.faults.clear()

    # ================================================================== gripper
    async def gripper(self, tool: str, width_m: float | None = None, force_n: float | None = None,
                      speed_mps: float | None = None, epsilon_inner_m: float = 0.005,
                      epsilon_outer_m: float = 0.005) -> GripperResultModel:
        self.admit(tool)
        self.require_audit(tool)
        self.require_not_estopped(tool)
        cfg = self.policy.gripper
        if cfg is None:
            raise refuse("NOT_CONFIGURED", "the policy has no gripper section")
        speed = cfg.max_speed_mps if speed_mps is None else speed_mps
        if width_m is not None and not (cfg.min_width_m <= width_m <= cfg.max_width_m):
            raise refuse("OUT_OF_RANGE", f"width_m {width_m:g} must be in [{cfg.min_width_m:g}, {cfg.max_width_m:g}] m")
        if not (0.0 < speed <= cfg.max_speed_mps):
            raise refuse("OUT_OF_RANGE", f"speed_mps {speed:g} must be in (0, {cfg.max_speed_mps:g}] m/s")
        if force_n is not None and not (0.0 < force_n <= cfg.max_grasp_force_n):
            raise refuse("OUT_OF_RANGE", f"force_n {force_n:g} must be in (0, {cfg.max_grasp_force_n:g}] N")
        for name, eps in (("epsilon_inner_m", epsilon_inner_m), ("epsilon_outer_m", epsilon_outer_m)):
            if not (0.0 <= eps <= cfg.max_width_m):
                raise refuse("OUT_OF_RANGE", f"{name} {eps:g} must be in [0, {cfg.max_width_m:g}] m")
        if self._gripper_busy:
            raise refuse("BUSY", "another gripper action is running")
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
                result = await self._backend_call(tool.replace("_", " "), call)
            except anyio.get_cancelled_exc_class():
                with anyio.CancelScope(shield=True):
                    await self.stop_motion()
                raise
        finally:
            self._gripper_busy = False
        return GripperResultModel(
            status="succeeded" if result.success else "failed",
            width_m=result.width_m,
            is_grasped=result.is_grasped,
            detail=result.detail or ("done" if result.success else "the gripper action did not succeed"),
        )

    # ================================================================== camera
    async def camera(self, camera: str) -> tuple[int, int, float, bytes]:
        self.admit("camera_snapshot")
        allowed = self.policy.perception.cameras
        if camera not in allowed:
            raise refuse("NOT_ALLOWED", f"camera {flatten_reason(camera, 64)!r} is not allowlisted; allowed: {list(allowed)}")
        image = await self._backend_call("take a snapshot", self.backend.camera_snapshot(camera))
        png, width, height = image.png, image.width, image.height
        limit = self.policy.perception.max_image_width
        if width > limit:
            from armwarden.server.images import downscale_png, pillow_available

            if not pillow_available():
                raise refuse("IMAGE_TOO_WIDE", f"the image is {width} px wide (limit {limit}) and Pillow is not installed to shrink it")
            png, width, height = await anyio.to_thread.run_sync(downscale_png, png, limit)
        return width, height, image.stamp, png


_NO_WRENCH_MESSAGE = (
    "this backend provides no wrench estimate, so the contact force limit cannot be enforced, and the "
    "policy requires it (force.require_wrench: true); nothing was moved"
)

__all__ = ["Approval", "Guard", "Prompt", "refuse"]
