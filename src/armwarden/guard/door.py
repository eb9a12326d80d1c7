"""The Guard: the one door to the robot.

Every actuation (trajectory, gripper, controller switch, threshold change, error recovery) and
every backend read goes through a Guard method; the tool layer never touches the backend. The
Guard holds no check logic of its own: it builds the state its flows share and the gates over it
(`GuardState` in `gates.py`: rate limiter, e-stop latch, plan store, `admit`, `require_audit`,
`require_not_estopped`, `interpret_approval`), owns the execution slot, and each flow runs the
gates in its order, refusing with a `SafetyRefusal` at the first that says no. The order is data in `order.py` (tested there, printed
in docs/tools.md). The tool layer admits every call first (rate limit, `ToolBuilder.answer` in
`server/registration.py`); then:

- execute_plan (here): audit writable → execution slot free (claimed) → the plan
  (`safety.plans`: exists, unexpired, this caller's, made since the last e-stop; spent from here
  on) → approval granted, and given for this plan (`safety.approval`) → e-stop latch →
  re-validation on the planning thread (envelope) → arm still at the plan's start → force
  monitor armed and `execution_started` audited (`execution`) → no stop or e-stop since the slot
  was claimed → dry run ends here → move (`execution.MotionRunner.run`);
- plan_* (`planning`): e-stop latch → fresh state → plan and envelope check → no e-stop since;
- gripper_* (`gripper`): audit → e-stop latch → arguments (`safety.checks`) → one at a time;
- switch_controllers, set_collision_thresholds, error_recovery (`actions`): arguments → audit
  → e-stop latch → approval, given for this very request;
- reset_estop: audit writable → approval → the release recorded → release of the event shown
  (`stopping.Stopper.release`; a release that cannot be recorded does not happen);
- stop_motion, emergency_stop (`stopping`): no rate limit, no approval, no gate; they wait for
  nothing but the backend's stop, and a stop that fails latches the e-stop;
- reads (`readings`): fresh data or a refusal.

Approval resolvers call the `precheck_*` methods, which only read state (under protocol
2026-07-28 a resolver may run more than once per call) and refuse before any human is asked
(prompts in `safety.prompts`); everything that changes state happens in the action methods,
which the tool body calls once.

Concurrency model. The Guard lives on the event loop. Planning and envelope checks run on one
worker thread with their own Pinocchio data (`planning`), so a long IK search never delays a
stop; state queries use a second, loop-side model. An execution claims the slot synchronously
and checks the stop generation and the latch right before handing the trajectory over, so a
stop that arrives during its checks wins.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from armwarden import conversions, results
from armwarden.approval import prompts
from armwarden.approval.board import PendingApprovals
from armwarden.approval.decision import Prompt, ServerDecision, approval_required, client_decision
from armwarden.approval.plans import PlanRefusal, PlanStore
from armwarden.backends.base import Backend
from armwarden.backends.parts import Capabilities
from armwarden.callcontext import current_call, current_caller
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard.actions import ControlActions, ControlTool
from armwarden.guard.execution import Execution, MotionRunner, ProgressReporter, contact_source, no_contact_message
from armwarden.guard.gates import GuardState
from armwarden.guard.gripper import GripperFlow, GripperTool
from armwarden.guard.planning import PlanningFlow, Previewer, stored_summary
from armwarden.guard.readings import Readings
from armwarden.guard.stopping import Stopper
from armwarden.policy import Policy
from armwarden.preflight import RuntimeModel
from armwarden.robot.model import RobotModel
from armwarden.safety.estop import EStopLatch
from armwarden.safety.ratelimit import RateLimiter
from armwarden.safety.violations import Violation
from armwarden.tools import PlanKind

logger = logging.getLogger(__name__)


def refuse(code: RefusalCode | str, message: str) -> SafetyRefusal:
    return SafetyRefusal(code, message)


class Guard:
    """The safety pipeline; see the module docstring."""

    def __init__(self, policy: Policy, planning: RuntimeModel, state_robot: RobotModel, backend: Backend, *,
                 audit=None, previewer: Previewer | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.policy = policy
        self.robot = state_robot
        self.backend = backend
        self.audit = audit
        self._clock = clock
        self.limiter = RateLimiter.from_policy(policy, clock=clock)
        self.latch = EStopLatch(clock=clock)
        self.plans = PlanStore.from_policy(policy, clock=clock)
        #: approval questions asked about plans, for the operator console (`safety.pending`)
        self.approvals = PendingApprovals(clock=clock)
        self.readings = Readings(policy, state_robot, backend, clock)
        self.stopper = Stopper(backend, self.latch, self.plans, audit)
        self.faults = self.stopper.faults  # one list: stops, the audit writer and error recovery add to it
        #: what the flows share, and the gates they run (`gates.py`)
        self.state = GuardState(policy, planning, backend, self.readings, self.limiter, self.latch, self.plans,
                                self.stopper, audit)
        backend.set_fault_listener(self._backend_fault)  # faults a backend finds on its own thread
        self.runner = MotionRunner(backend, policy, self.latch, clock=clock, audit=audit,
                                   emergency_stop=self.emergency_stop, stop_for=self.stopper.stop_for,
                                   record=self._record, robot=state_robot)
        self.planning_flow = PlanningFlow(self.state, previewer)
        self._execution: Execution | None = None
        self.actions = ControlActions(self.state)
        self.gripper_flow = GripperFlow(self.state)

    # ================================================================== admission (the gates: gates.py)
    @property
    def dry_run(self) -> bool:
        return self.policy.dry_run

    @property
    def capabilities(self) -> Capabilities:
        return self.backend.capabilities

    @property
    def planning(self) -> RuntimeModel:
        return self.state.planning

    @property
    def last_violation(self) -> Violation | None:
        return self.state.last_violation

    @property
    def last_result(self) -> results.ExecutionReport | None:
        return self.state.last_result

    def admit(self, tool: str) -> None:
        self.state.admit(tool)

    def charge(self, tool: str) -> None:
        self.state.charge(tool)

    def peek_rate(self, tool: str) -> ServerDecision | None:
        return self.state.peek_rate(tool)

    def estop_refusal(self, what: str) -> SafetyRefusal | None:
        return self.state.estop_refusal(what)

    def audit_unusable(self) -> str | None:
        return self.state.audit_unusable()

    def require_audit(self, what: str) -> None:
        self.state.require_audit(what)

    def require_not_estopped(self, what: str) -> None:
        self.state.require_not_estopped(what)

    # ================================================================== introspection (reads only, see readings.py)
    async def robot_state(self) -> results.RobotState:
        return await self.readings.robot_state()

    async def robot_state_data(self) -> dict[str, Any]:
        """`robot_state` as plain JSON data, for a caller whose boundary validates it (the tool)."""
        return await self.readings.robot_state_data()

    def safety_envelope(self, registered_tools: list[str]) -> results.EnvelopeModel:
        return self.readings.safety_envelope(registered_tools)

    async def lookup_transform(self, target_frame: str, source_frame: str) -> results.TransformResult:
        return await self.readings.lookup_transform(target_frame, source_frame)

    async def list_controllers(self) -> results.ControllerList:
        return await self.readings.list_controllers()

    async def graph(self) -> results.GraphModel:
        return await self.readings.graph()

    async def camera(self, camera: str) -> tuple[int, int, float, bytes]:
        return await self.readings.camera(camera)

    def motion_status(self) -> results.MotionStatus:
        execution = self._execution
        return results.MotionStatus(
            executing=execution is not None,
            plan_id=None if execution is None else execution.plan_id,
            progress=0.0 if execution is None else min(1.0, max(0.0, execution.progress)),
            last_result=self.last_result,
        )

    def safety_status(self) -> results.SafetyStatus:
        audit_error = self.audit_unusable()
        return results.SafetyStatus(
            estopped=self.latch.is_latched,
            estop_event=conversions.estop_info(self.latch.current_event or self.latch.last_event),
            force_violation_latched=self.force_violation_latched and self.latch.is_latched,
            dry_run=self.dry_run,
            last_violation=None if self.last_violation is None else conversions.violation_model(self.last_violation),
            faults=list(self.faults),
            audit_ok=audit_error is None,
            audit_error=audit_error,
        )

    # ================================================================== planning (see planning.py)
    async def plan(self, kind: PlanKind, request: dict[str, Any]) -> tuple[results.PlanSummary, bytes | None]:
        """Plan and check a motion (never moves); the plan belongs to the caller. Returns the
        summary and an optional preview PNG."""
        return await self.planning_flow.plan(kind, request)

    def plan_summary(self, plan_id: object) -> results.PlanSummary:
        """A plan this caller made and could still run, summarised as its plan_* call was (reads
        only: the plan stays usable). Refuses as execute_plan would for a plan that cannot run."""
        plan = self.plans.peek(plan_id, self.latch.generation, current_caller())
        if isinstance(plan, PlanRefusal):
            raise refuse(plan.code, plan.message)
        return stored_summary(plan, contact_source(self.policy, self.backend) is not None)

    # ================================================================== execution
    async def precheck_execute(self, plan_id: object, can_elicit: bool) -> ServerDecision | Prompt:
        """Everything that would refuse execute_plan, checked before any human is asked. Read-only,
        but for posting the question on the approval board (idempotent per plan and e-stop generation)."""
        if (d := self.peek_rate("execute_plan")) is not None:
            return d
        if (r := self.estop_refusal("execute_plan")) is not None:
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
        monitored = contact_source(self.policy, self.backend) is not None
        if not monitored and self.policy.force.require_wrench:
            return ServerDecision.refused(RefusalCode.NO_WRENCH, no_contact_message(self.policy, self.backend))
        required = approval_required(self.policy, "execute", bool(plan.report.soft))
        decision = client_decision(self.policy, "execute_plan", required, can_elicit)
        if decision is not None:
            return decision
        prompt = prompts.execute_prompt(self.policy, plan, self.backend.name, monitored, self.dry_run)
        call = current_call()  # the requester: its token may not approve in the console (safety.pending)
        self.approvals.offer(plan, prompt.message, self.latch.generation, self.stopper.generation,  # idempotent: the console shows it
                             requester=None if call is None else call.principal)
        return prompt

    async def execute(self, plan_id: str, approval_outcome: Any, shown_digest: str | None,
                      report_progress: ProgressReporter | None = None) -> results.ExecutionReport:
        """Run a stored plan: the only way the arm moves. The tool layer has admitted the call (rate
        limit); the rest of the order is the module docstring's. Each check here re-checks, at the
        last moment, something that may have changed since planning or while a human decided."""
        self.require_audit("execute_plan")
        if self._execution is not None:
            raise refuse(RefusalCode.BUSY, f"plan {self._execution.plan_id} is still executing; the plan {plan_id} stays usable")
        # claimed synchronously; a stop from any path or thread after this moment wins (stop epoch)
        execution = self._execution = Execution(plan_id=str(plan_id), stop_epoch=self.backend.stop_epoch)
        stop_generation = self.stopper.generation
        try:
            # from here on the plan is spent, whatever happens (unless it is not this caller's)
            plan = self.plans.consume(plan_id, self.latch.generation, current_caller())
            if isinstance(plan, PlanRefusal):
                raise refuse(plan.code, plan.message)
            asked_at = self.approvals.asked_at(plan.plan_id, self.latch.generation)
            self.approvals.withdraw(plan.plan_id, "the plan was used")
            approval = self.state.interpret_approval(approval_outcome, approval_required(self.policy, "execute", bool(plan.report.soft)))
            if not approval.granted:
                raise approval.refusal(f"execute_plan {plan.plan_id}")
            asked_a_human = approval.via in ("elicitation", "console")
            if asked_a_human and asked_at is not None and asked_at != self.stopper.generation:
                raise refuse(RefusalCode.STOPPED, "a stop arrived while a human was deciding about this plan; the approval "
                             "does not outlast it and nothing moved (plan again to ask again)")
            if asked_a_human and shown_digest != plan.digest:
                raise refuse(RefusalCode.APPROVAL_MISMATCH, "the approval was given for a different plan; nothing was done")
            self.require_not_estopped("execute_plan")
            recheck = await self.planning_flow.on_thread(lambda: self.state.planning.envelope.check(plan.trajectory))
            if recheck.hard:
                self.state.last_violation = recheck.hard[0]
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
                return self._record(results.ExecutionReport(
                    plan_id=plan.plan_id, status="dry_run", approval=approval.info(), duration_s=0.0,
                    max_observed_force_n=None, detail="dry run: validated and approved, nothing moved"))
            return await self.runner.run(plan, execution, approval, monitor, report_progress)
        finally:
            if self._execution is execution:
                self._execution = None

    def _backend_fault(self, reason: str) -> None:
        """From the backend's thread (a fault it found, a thread of its own that died): latch the
        e-stop (`Stopper.backend_fault`) and record it, handed to the audit writer without waiting
        (the latch holds whether or not the record can be written; a lost one is said loudly)."""
        event = self.stopper.backend_fault(reason)
        if self.audit is None:
            return
        try:
            self.audit.submit("backend_fault", outcome="latched", detail=f"e-stop #{event.number}: {reason}",
                              extra={"estop_event": event.number})
        except Exception as exc:
            logger.critical("backend fault not audited (%s): e-stop #%d: %s", exc, event.number, reason)

    def _record(self, report: results.ExecutionReport) -> results.ExecutionReport:
        self.state.last_result = report
        return report

    async def abandoned_call(self, tool: str, arguments: dict[str, Any], request_id: Any, cancelled: bool | None,
                             principal: str | None = None) -> None:
        """An HTTP client went away before its motion call answered (`transport/abandoned.py`).

        `cancelled` True: the call was cancelled in its session and the cancellation path stopped
        whatever it moved. None: a sessionless (2026-07-28) call, which the SDK ends with its
        request. False: the cancellation could not be delivered; if that call's motion still runs
        (same plan id; the one gripper action), it is stopped here. Audited in every case."""
        running = cancelled is False and (
            self._execution is not None and self._execution.plan_id == arguments.get("plan_id")
            if tool == "execute_plan" else self.gripper_flow.busy)
        outcome, detail = await self.stopper.after_abandoned_call(tool, request_id, cancelled, running)
        if self.audit is not None:
            await self.audit.append_async("client_disconnected", principal=principal, tool=tool, arguments=arguments,
                                          outcome=outcome, detail=detail)

    # ================================================================== stop and e-stop (see stopping.py)
    async def stop_motion(self) -> results.StopResult:
        """Stop arm and gripper now. Never rate limited, never needs approval."""
        return await self.stopper.stop_motion()

    async def emergency_stop(self, reason: object, source: str = "estop", force: dict | None = None) -> results.EStopResult:
        """Latch, invalidate every plan and stop arm and gripper. Accepts any reason. The token of
        the call that latched (also a force violation during its motion) is remembered: it may
        not release that e-stop in the console (`PendingApprovals.self_release`)."""
        result = await self.stopper.emergency_stop(reason, source, force)
        if (call := current_call()) is not None:
            self.approvals.note_release_party(result.estop_event.number, call.principal, "latched it over MCP")
        return result

    @property
    def force_violation_latched(self) -> bool:
        return self.stopper.force_violation_latched

    def precheck_reset(self, can_elicit: bool) -> ServerDecision | Prompt:
        event = self.latch.current_event
        if event is None:
            return ServerDecision.refused(RefusalCode.NOT_ESTOPPED, "the e-stop is not latched; nothing to reset")
        if (call := current_call()) is not None:  # who asked may not release it in the console (idempotent)
            self.approvals.note_release_party(event.number, call.principal, "asked over MCP to release it")
        if (why := self.audit_unusable()) is not None:  # a release could not be recorded: do not ask anyone
            return ServerDecision.refused(RefusalCode.AUDIT_UNAVAILABLE, f"reset_estop refused: the audit log cannot be "
                                          f"written ({why}), so no release can be recorded and none is made: e-stop "
                                          f"#{event.number} stays latched")
        decision = client_decision(self.policy, "reset_estop", True, can_elicit)
        return decision if decision is not None else prompts.reset_prompt(event, self.latch.held_events)

    async def reset_estop(self, approval_outcome: Any, shown_event: str | None) -> results.ResetResult:
        """Release the e-stop a human approved resetting; recorded before it takes effect."""
        approval = self.state.interpret_approval(approval_outcome, True)
        if not approval.granted:
            raise approval.refusal("reset_estop")
        return await self.stopper.release(shown_event, approval.operator, approval.via)

    async def reset_estop_typed(self, typed_event: str, operator: str | None = None) -> results.ResetResult:
        """Release from the operator console: a signed-in operator typed the number of the event
        they were shown (the console's equivalent of approving `reset_estop`). Only that event,
        only while it is still the one latched, and only once the release is recorded."""
        if not (isinstance(typed_event, str) and typed_event.isascii() and typed_event.isdigit()):
            raise refuse(RefusalCode.RESET_REFUSED, "reset refused: type the number of the latched e-stop event")
        return await self.stopper.release(typed_event, operator, "console")

    # ================================================================== control actions and gripper (own modules)
    def precheck_action(self, tool: ControlTool, can_elicit: bool, **arguments: Any) -> ServerDecision | Prompt:
        """Pre-check for switch_controllers, set_collision_thresholds, error_recovery. Read-only."""
        return self.actions.precheck(tool, can_elicit, arguments)

    async def run_action(self, tool: ControlTool, approval_outcome: Any, shown: str | None, **arguments: Any) -> results.ActionResult:
        return await self.actions.run(tool, approval_outcome, shown, arguments)

    async def gripper(self, tool: GripperTool, width_m: float | None = None, force_n: float | None = None,
                      speed_mps: float | None = None, epsilon_inner_m: float = 0.005,
                      epsilon_outer_m: float = 0.005) -> results.GripperResultModel:
        return await self.gripper_flow.run(tool, width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)


__all__ = ["Guard", "refuse"]
