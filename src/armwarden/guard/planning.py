"""Planning: build and check a motion, never move it.

Order: e-stop latch → fresh joint state → plan and envelope check (and the preview) on the
planning thread → no e-stop since the start → the verdict (hard violation: rejected; soft or
`approval.mode`: needs approval) → the plan stored for this caller (`safety.plans`).

`plan_offline` is the pure core of that (plan, check, verdict) for one policy and one start state,
with no backend, no store and no server: the daemon's flow and `armwarden audit replay` both use
it. Each planning call notes on its audit record what a replay needs (`replay_facts`).

Planning and envelope checks run on one worker thread with their own Pinocchio data (the
`RuntimeModel`), one at a time, so a long IK search never delays a stop; the execution's
re-validation uses the same thread (`on_thread`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import anyio
import numpy as np

from armwarden import __version__, conversions
from armwarden.approval.decision import approval_required
from armwarden.approval.plans import StoredPlan
from armwarden.callcontext import current_call, current_caller
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.core.trajectory import JointTrajectory
from armwarden.guard.execution import contact_source
from armwarden.guard.gates import GuardState
from armwarden.planning.around import request_seed
from armwarden.planning.planners import PlanOutcome, PoseTarget
from armwarden.policy import Policy, policy_digest
from armwarden.preflight import RuntimeModel
from armwarden.results import PlanSummary
from armwarden.safety.limits import EnvelopeReport
from armwarden.safety.violations import Violation
from armwarden.tools import PlanKind

PlanStatus = Literal["ok", "needs_approval", "rejected"]
#: version of the `replay` object a planning call's audit record carries (`replay_facts`)
REPLAY_FORMAT = 1
#: renders the preview picture (PNG) of a checked plan; None when it cannot be drawn
Previewer = Callable[[RuntimeModel, JointTrajectory, EnvelopeReport], "bytes | None"]

T = TypeVar("T")


def stored_summary(plan: StoredPlan, force_monitoring: bool) -> PlanSummary:
    """The summary of a stored plan: what its plan_* call answered, and what get_plan reads back
    (from the facts the planning flow keeps with the plan)."""
    return conversions.plan_summary(
        list(plan.meta["violations"]), list(plan.meta["notes"]), force_monitoring, report=plan.report,
        plan_id=plan.plan_id, status=plan.status, requires_approval=plan.meta["requires_approval"],
        duration_s=plan.trajectory.duration_s, expires_at=plan.expires_at_wall)


def plan_and_check(
    model: RuntimeModel, kind: PlanKind, start: np.ndarray, request: dict[str, Any],
    should_stop: Callable[[], bool] = lambda: False,
) -> tuple[PlanOutcome, EnvelopeReport | None]:
    """The straight-line planner's proposal and the envelope's verdict on it. When the verdict is
    one a different path could change (`DetourPlanner.worth_trying`), the detour planner's
    proposal replaces it and the envelope checks that one instead: the envelope's `check` is the
    last word on whatever is returned. `should_stop` ends a detour search early (an e-stop)."""
    vel, acc = request.get("velocity_scaling"), request.get("acceleration_scaling")
    if kind == "joints":
        outcome = model.planner.plan_to_joints(start, request["joint_positions"], vel, acc)
    elif kind == "pose":
        outcome = model.planner.plan_to_pose(start, request["target"], vel, acc)
    else:
        outcome = model.planner.plan_cartesian_path(start, request["waypoints"], vel, acc)
    if outcome.trajectory is None:
        return outcome, None
    report = model.envelope.check(outcome.trajectory)
    detours = model.detours
    if detours is None or kind == "cartesian" or not detours.worth_trying(kind, report):
        return outcome, report
    proposal = detours.plan(kind, start, outcome, report, target=request.get("target"), should_stop=should_stop)
    if proposal.trajectory is outcome.trajectory:
        return proposal, report  # no detour: the straight line's verdict stands, with the reason why
    return proposal, model.envelope.check(proposal.trajectory)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Verdict:
    """What a checked plan may do: its status and every finding (the planner's, then the envelope's)."""

    status: PlanStatus
    violations: tuple[Violation, ...]
    requires_approval: bool


def judge(policy: Policy, outcome: PlanOutcome, report: EnvelopeReport | None) -> Verdict:
    """The verdict on a planned and checked motion: nothing planned or a hard violation → rejected;
    otherwise `approval` decides whether a human must approve (soft violations in
    `outside_envelope` mode, always in `always` mode)."""
    violations = tuple(outcome.violations) + (tuple(report.violations) if report is not None else ())
    if outcome.trajectory is None or report is None:
        return Verdict("rejected", violations, False)
    hard = any(v.is_hard for v in violations)
    needs = not hard and approval_required(policy, "execute", any(not v.is_hard for v in violations))
    return Verdict("rejected" if hard else ("needs_approval" if needs else "ok"), violations, needs)


def plan_offline(
    model: RuntimeModel, kind: PlanKind, start: np.ndarray, request: dict[str, Any],
    should_stop: Callable[[], bool] = lambda: False,
) -> tuple[PlanOutcome, EnvelopeReport | None, Verdict]:
    """Plan `request` from `start` against `model`'s policy, check it and judge it: what the daemon
    would answer, without a backend, a plan store or a server (the planning thread's work)."""
    outcome, report = plan_and_check(model, kind, start, request, should_stop)
    return outcome, report, judge(model.policy, outcome, report)


def replay_facts(digest: str, model: RuntimeModel, kind: PlanKind, start: np.ndarray,
                 request: dict[str, Any]) -> dict[str, Any]:
    """What a planning call's audit record carries so that `armwarden audit replay` can plan it
    again offline: the start joint state [rad] the plan was made from (exact floats), the request as
    the planner received it, the digest of the policy in force (`policy_digest`), and the planner
    settings that shape the outcome (the detour search's seed derives from request and start state)."""
    start = np.asarray(start, dtype=float)
    planner = {
        "version": __version__,
        "detours": model.detours is not None,
        "planning_time_s": model.policy.motion.planning_time_s,
        "cartesian_step_m": model.planner.settings.cartesian_step_m,
        "cartesian_step_rad": model.planner.settings.cartesian_step_rad,
        "max_ik_jump_rad": model.planner.settings.max_ik_jump_rad,
    }
    if kind == "joints":
        planner["seed"] = request_seed(kind, start, np.asarray(request["joint_positions"], dtype=float))
    elif kind == "pose":
        planner["seed"] = request_seed(kind, start, request["target"])
    return {
        "format": REPLAY_FORMAT,
        "kind": kind,
        "start_q": start.tolist(),
        "request": encode_request(kind, request),
        "policy_digest": digest,
        "planner": planner,
    }


def encode_request(kind: PlanKind, request: dict[str, Any]) -> dict[str, Any]:
    """The planner's input as plain JSON (rotation matrices row-major, 9 numbers); `decode_request`
    inverts it exactly (JSON floats round-trip)."""
    encoded: dict[str, Any] = {"velocity_scaling": request.get("velocity_scaling"),
                               "acceleration_scaling": request.get("acceleration_scaling")}
    if kind == "joints":
        encoded["joint_positions"] = np.asarray(request["joint_positions"], dtype=float).tolist()
    elif kind == "pose":
        encoded["target"] = _encode_target(request["target"])
    else:
        encoded["waypoints"] = [_encode_target(target) for target in request["waypoints"]]
    return encoded


def decode_request(kind: PlanKind, encoded: dict[str, Any]) -> dict[str, Any]:
    """The planner's input from `encode_request`'s JSON. Raises ValueError/KeyError/TypeError on a
    malformed one."""
    request: dict[str, Any] = {"velocity_scaling": _number_or_none(encoded.get("velocity_scaling")),
                               "acceleration_scaling": _number_or_none(encoded.get("acceleration_scaling"))}
    if kind == "joints":
        request["joint_positions"] = _floats(encoded["joint_positions"])
    elif kind == "pose":
        request["target"] = _decode_target(encoded["target"])
    elif kind == "cartesian":
        request["waypoints"] = [_decode_target(target) for target in encoded["waypoints"]]
    else:
        raise ValueError(f"unknown plan kind {kind!r}")
    return request


def _encode_target(target: PoseTarget) -> dict[str, Any]:
    rotation = None if target.rotation is None else np.asarray(target.rotation, dtype=float).reshape(9).tolist()
    encoded: dict[str, Any] = {"position": np.asarray(target.position, dtype=float).tolist(), "rotation": rotation}
    if target.free_yaw:  # only when asked: records of exact-rotation requests keep their form
        encoded["free_yaw"] = True
    return encoded


def _decode_target(encoded: dict[str, Any]) -> PoseTarget:
    position = _floats(encoded["position"])
    if position.shape != (3,):
        raise ValueError(f"a target position has 3 numbers, got {position.size}")
    rotation = encoded.get("rotation")
    free_yaw = encoded.get("free_yaw", False)
    if type(free_yaw) is not bool:
        raise ValueError(f"free_yaw is true or false, got {str(free_yaw)[:80]}")
    return PoseTarget(position, None if rotation is None else _floats(rotation).reshape(3, 3), free_yaw)


def _floats(values: Any) -> np.ndarray:
    if not isinstance(values, list) or not all(type(v) in (int, float) for v in values):
        raise ValueError(f"expected a list of numbers, got {str(values)[:80]}")
    return np.array(values, dtype=float)


def _number_or_none(value: Any) -> float | None:
    if value is None:
        return None
    if type(value) not in (int, float):
        raise ValueError(f"expected a number or null, got {str(value)[:40]}")
    return float(value)


class PlanningFlow:
    """Plans for the Guard (with its `planning` model) on its one planning thread."""

    def __init__(self, state: GuardState, previewer: Previewer | None) -> None:
        self._state = state
        self._previewer = previewer
        self._slot = anyio.CapacityLimiter(1)  # one planning thread, one Pinocchio Data
        self._digest: tuple[Policy, str] | None = None  # the last policy digested and its digest

    def policy_digest(self, policy: Policy) -> str:
        """`policy_digest(policy)`, computed once per policy object (0.25 ms of canonical JSON and
        SHA-256 per planning call otherwise); policies are frozen, so the object names the content."""
        if self._digest is None or self._digest[0] is not policy:
            self._digest = (policy, policy_digest(policy))
        return self._digest[1]

    async def on_thread(self, fn: Callable[[], T]) -> T:
        """Run `fn` on the planning thread (its own Pinocchio data); one at a time."""
        return await anyio.to_thread.run_sync(fn, limiter=self._slot)

    async def plan(self, kind: PlanKind, request: dict[str, Any]) -> tuple[PlanSummary, bytes | None]:
        """Plan and check a motion (never moves); the plan belongs to the caller. Returns the
        summary and an optional preview PNG."""
        state = self._state
        generation = state.latch.generation  # an e-stop from now on (any thread) voids the result ...
        state.require_not_estopped("planning")  # ... and one before it refuses
        start = (await state.readings.joint_state()).positions.copy()
        model, previewer = state.planning, self._previewer  # the Guard's model, as it is now
        call = current_call()
        if call is not None:  # before planning: a call that fails while planning can be replayed too
            call.extra["replay"] = replay_facts(self.policy_digest(state.policy), model, kind, start, request)

        def work() -> tuple[Any, EnvelopeReport | None, bytes | None]:
            outcome, report = plan_and_check(model, kind, start, request, lambda: state.latch.generation != generation)
            if outcome.trajectory is None or report is None:
                return outcome, None, None
            wants_preview = request.get("preview", True) and previewer is not None
            preview = previewer(model, outcome.trajectory, report) if wants_preview and previewer else None
            return outcome, report, preview

        outcome, report, preview = await self.on_thread(work)
        if call is not None:  # the scalings the planner used (after the policy's caps)
            call.extra["replay"]["planner"].update(velocity_scaling=outcome.velocity_scaling,
                                                   acceleration_scaling=outcome.acceleration_scaling)
        if state.latch.generation != generation:
            raise SafetyRefusal(RefusalCode.ESTOPPED, "an e-stop latched while this motion was being planned; the plan "
                                "was discarded. A human must approve reset_estop before anything can move again.")
        verdict = judge(state.policy, outcome, report)
        violations = list(verdict.violations)
        hard = [v for v in violations if v.is_hard]
        if violations:
            state.last_violation = hard[0] if hard else violations[0]
        monitoring = contact_source(state.policy, state.backend) is not None
        notes = conversions.plan_notes(outcome.notes, monitoring, state.policy.force.require_wrench, state.dry_run)
        if outcome.trajectory is None or report is None:
            return conversions.plan_summary(violations, notes, monitoring), preview
        status, needs = verdict.status, verdict.requires_approval
        stored = state.plans.add(outcome.trajectory, report, status=status, estop_generation=generation,
                                owner=current_caller(),
                                meta={"kind": kind, "notes": tuple(notes), "velocity_scaling": outcome.velocity_scaling,
                                      "violations": tuple(violations), "requires_approval": needs})
        return stored_summary(stored, monitoring), preview
