"""Planning: build and check a motion, never move it.

Order: e-stop latch → fresh joint state → plan and envelope check (and the preview) on the
planning thread → no e-stop since the start → the verdict (hard violation: rejected; soft or
`approval.mode`: needs approval) → the plan stored for this caller (`safety.plans`).

Planning and envelope checks run on one worker thread with their own Pinocchio data (the
`RuntimeModel`), one at a time, so a long IK search never delays a stop; the execution's
re-validation uses the same thread (`on_thread`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import anyio
import numpy as np

from armwarden import conversions
from armwarden.callcontext import current_caller
from armwarden.errors import RefusalCode, SafetyRefusal
from armwarden.planning.planners import PlanOutcome
from armwarden.planning.trajectory import JointTrajectory
from armwarden.preflight import RuntimeModel
from armwarden.results import PlanSummary
from armwarden.safety.approval import approval_required
from armwarden.safety.envelope import EnvelopeReport

if TYPE_CHECKING:
    from armwarden.guard.door import Guard

PlanKind = Literal["joints", "pose", "cartesian"]
#: renders the preview picture (PNG) of a checked plan; None when it cannot be drawn
Previewer = Callable[[RuntimeModel, JointTrajectory, EnvelopeReport], "bytes | None"]

T = TypeVar("T")


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


class PlanningFlow:
    """Plans for the Guard (with its `planning` model) on its one planning thread."""

    def __init__(self, door: Guard, previewer: Previewer | None) -> None:
        self._door = door
        self._previewer = previewer
        self._slot = anyio.CapacityLimiter(1)  # one planning thread, one Pinocchio Data

    async def on_thread(self, fn: Callable[[], T]) -> T:
        """Run `fn` on the planning thread (its own Pinocchio data); one at a time."""
        return await anyio.to_thread.run_sync(fn, limiter=self._slot)

    async def plan(self, kind: PlanKind, request: dict[str, Any]) -> tuple[PlanSummary, bytes | None]:
        """Plan and check a motion (never moves); the plan belongs to the caller. Returns the
        summary and an optional preview PNG."""
        door = self._door
        door.require_not_estopped("planning")
        generation = door.latch.generation  # an e-stop while planning voids the result
        start = (await door.readings.joint_state()).positions.copy()
        model, previewer = door.planning, self._previewer  # the Guard's model, as it is now

        def work() -> tuple[Any, EnvelopeReport | None, bytes | None]:
            outcome, report = plan_and_check(model, kind, start, request, lambda: door.latch.generation != generation)
            if outcome.trajectory is None or report is None:
                return outcome, None, None
            wants_preview = request.get("preview", True) and previewer is not None
            preview = previewer(model, outcome.trajectory, report) if wants_preview and previewer else None
            return outcome, report, preview

        outcome, report, preview = await self.on_thread(work)
        if door.latch.generation != generation:
            raise SafetyRefusal(RefusalCode.ESTOPPED, "an e-stop latched while this motion was being planned; the plan "
                                "was discarded. A human must approve reset_estop before anything can move again.")
        violations = list(outcome.violations) + (list(report.violations) if report else [])
        hard = [v for v in violations if v.is_hard]
        if violations:
            door.last_violation = hard[0] if hard else violations[0]
        monitoring = door.backend.capabilities.wrench
        notes = conversions.plan_notes(outcome.notes, monitoring, door.policy.force.require_wrench, door.dry_run)
        if outcome.trajectory is None or report is None:
            return conversions.plan_summary(violations, notes, monitoring), preview
        needs = not hard and approval_required(door.policy, "execute", any(not v.is_hard for v in violations))
        status = "rejected" if hard else ("needs_approval" if needs else "ok")
        stored = door.plans.add(outcome.trajectory, report, status=status, estop_generation=generation,
                                owner=current_caller(),
                                meta={"kind": kind, "notes": tuple(notes), "velocity_scaling": outcome.velocity_scaling})
        return conversions.plan_summary(
            violations, notes, monitoring, report=report, plan_id=stored.plan_id, status=status, requires_approval=needs,
            duration_s=outcome.trajectory.duration_s, expires_at=stored.expires_at_wall), preview
