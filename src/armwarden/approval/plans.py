"""The plan store: checked trajectories, kept server-side, each runnable at most once.

Why: the model never sends a trajectory to execute, only the id of one the server planned and
checked. An id is random (unguessable), expires (TTL on the monotonic clock, so wall-clock
jumps change nothing), is bound to the joint state it starts from and to the caller that made
it (its owner: another caller who learns the id cannot run it), and is spent the moment its
owner's `execute_plan` examines it, whatever the outcome, so a replay can never move the arm
twice. An e-stop invalidates every outstanding plan (docs/stopping.md).

`peek` only reads (approval resolvers may run several times); `consume` removes the plan in
the same step as it returns it. Ids that are gone are remembered (bounded) with the reason, so
a replay is told "already used" or "invalidated", not "unknown". Every refusal is a
`PlanRefusal` with a stable code and a message for the model and the human.

Not thread safe: the Guard uses it from the event loop only, and no method awaits.
"""

from __future__ import annotations

import math
import secrets
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal, TypeGuard

import numpy as np

from armwarden.conversions import iso_utc
from armwarden.core.errors import ConfigurationError, RefusalCode
from armwarden.core.trajectory import JointTrajectory
from armwarden.safety.estop import flatten_reason
from armwarden.safety.limits import EnvelopeReport

__all__ = ["PLAN_ID_PREFIX", "PlanRefusal", "PlanStatus", "PlanStore", "RefusalCode", "StoredPlan"]

PlanStatus = Literal["ok", "needs_approval", "rejected"]

PLAN_ID_PREFIX = "plan_"
#: longest string looked up as a plan id; anything longer is unknown without further ado
MAX_PLAN_ID_LENGTH = 64
#: how many spent/invalidated/expired ids are remembered to explain a replay
RETIRED_MEMORY = 4096


@dataclass(frozen=True)
class PlanRefusal:
    """Why a plan id cannot be used: a stable code and a message for the model and the human."""

    code: RefusalCode
    message: str


@dataclass(frozen=True, eq=False)
class StoredPlan:
    """A checked trajectory and everything needed to decide, later, whether it may still run."""

    plan_id: str
    trajectory: JointTrajectory
    report: EnvelopeReport
    status: PlanStatus
    #: joint positions [rad] the plan starts from (read-only), in `trajectory.joint_names` order
    start: np.ndarray
    digest: str
    created_mono: float
    expires_mono: float
    #: expiry as ISO 8601 UTC, for people and models (the store itself only uses `expires_mono`)
    expires_at_wall: str
    #: the e-stop latch generation when the plan was made
    estop_generation: int
    #: who made it (an opaque caller identity, see `armwarden.callcontext`); None: anyone may run it
    owner: str | None = None
    #: opaque data the Guard keeps with the plan (summary figures, request, ...); read-only
    meta: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


def _status_from_report(report: EnvelopeReport) -> PlanStatus:
    if report.hard:
        return "rejected"
    return "needs_approval" if report.soft else "ok"


def _start_of(trajectory: JointTrajectory) -> np.ndarray:
    """A read-only copy of the first waypoint; NaN (never "close enough") if there is none."""
    try:
        start = np.array(trajectory.start, dtype=float, copy=True).reshape(-1)
    except (IndexError, TypeError, ValueError):  # malformed: stored only to be rejected
        start = np.full(len(trajectory.joint_names), np.nan)
    start.setflags(write=False)
    return start



def _is_plausible_id(plan_id: object) -> TypeGuard[str]:
    return (
        isinstance(plan_id, str)
        and 0 < len(plan_id) <= MAX_PLAN_ID_LENGTH
        and plan_id.isascii()
        and plan_id.isprintable()
    )


class PlanStore:
    """Outstanding plans by id, with single use, expiry, start binding and invalidation."""

    def __init__(
        self,
        ttl_s: float,
        start_tolerance_rad: float,
        clock: Callable[[], float] = time.monotonic,
        max_plans: int = 256,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        if not (isinstance(ttl_s, (int, float)) and math.isfinite(ttl_s) and ttl_s > 0):
            raise ConfigurationError(f"plan ttl_s must be a positive number of seconds, got {ttl_s!r}")
        if not (isinstance(start_tolerance_rad, (int, float)) and math.isfinite(start_tolerance_rad)
                and start_tolerance_rad > 0):
            raise ConfigurationError(f"start_tolerance_rad must be a positive angle [rad], got {start_tolerance_rad!r}")
        if isinstance(max_plans, bool) or not isinstance(max_plans, int) or max_plans < 1:
            raise ConfigurationError(f"max_plans must be a positive integer, got {max_plans!r}")
        self.ttl_s = float(ttl_s)
        self.start_tolerance_rad = float(start_tolerance_rad)
        self.max_plans = max_plans
        self._clock = clock
        self._wall_clock = wall_clock
        self._plans: OrderedDict[str, StoredPlan] = OrderedDict()  # oldest first
        self._retired: OrderedDict[str, PlanRefusal] = OrderedDict()  # oldest first, bounded

    @classmethod
    def from_policy(
        cls, policy, clock: Callable[[], float] = time.monotonic, wall_clock: Callable[[], float] = time.time
    ) -> PlanStore:
        return cls(policy.motion.plan_ttl_s, policy.motion.start_tolerance_rad, clock=clock, wall_clock=wall_clock)

    def __len__(self) -> int:
        """Plans stored (expired ones included until they are next looked at or a plan is added)."""
        return len(self._plans)

    # ------------------------------------------------------------------ adding
    def add(
        self,
        trajectory: JointTrajectory,
        report: EnvelopeReport,
        *,
        status: PlanStatus | None = None,
        estop_generation: int = 0,
        owner: str | None = None,
        meta: Mapping[str, Any] | None = None,
    ) -> StoredPlan:
        """Store a checked plan and return it with its new id.

        `status` defaults to what the report implies (hard → rejected, soft → needs_approval);
        the Guard passes it when the approval mode decides otherwise. A report with hard
        violations is always stored as rejected: no caller can make it runnable. With an `owner`,
        only a lookup by that same caller finds the plan.
        """
        implied = _status_from_report(report)
        if status is None:
            status = implied
        if status not in ("ok", "needs_approval", "rejected"):
            raise ValueError(f"unknown plan status {status!r}")
        if implied == "rejected" and status != "rejected":
            raise ValueError(f"a plan with hard violations must be stored as rejected, not {status!r}")
        self._drop_expired()
        now = self._clock()
        start = _start_of(trajectory)
        plan = StoredPlan(
            plan_id=self._new_id(),
            trajectory=trajectory,
            report=report,
            status=status,
            start=start,
            digest=trajectory.digest,
            created_mono=now,
            expires_mono=now + self.ttl_s,
            expires_at_wall=iso_utc(self._wall_clock() + self.ttl_s),
            estop_generation=estop_generation,
            owner=owner,
            meta=MappingProxyType(dict(meta or {})),
        )
        self._plans[plan.plan_id] = plan
        while len(self._plans) > self.max_plans:
            old_id, _ = self._plans.popitem(last=False)
            self._retire(old_id, PlanRefusal(
                RefusalCode.EXPIRED_PLAN,
                f"plan {old_id} was discarded because more than {self.max_plans} newer plans were made; plan again",
            ))
        return plan

    def _new_id(self) -> str:
        while True:
            plan_id = PLAN_ID_PREFIX + secrets.token_urlsafe(16)
            if plan_id not in self._plans and plan_id not in self._retired:
                return plan_id

    # ------------------------------------------------------------------ lookup
    def peek(self, plan_id: object, estop_generation: int | None = None, caller: str | None = None
             ) -> StoredPlan | PlanRefusal:
        """The plan if it could run now, else why not. Reads only; call it as often as needed.

        With `estop_generation` (the latch's current one), a plan made under an earlier generation
        is refused: an e-stop latched after it was made, and nothing survives a reset. A plan with
        an owner other than `caller` is refused NOT_PLAN_OWNER and left untouched for its owner."""
        found = self._lookup(plan_id, estop_generation, caller)
        if isinstance(found, PlanRefusal):
            return found
        if found.status == "rejected":
            return self._rejected(found)
        return found

    def consume(self, plan_id: object, estop_generation: int | None = None, caller: str | None = None
                ) -> StoredPlan | PlanRefusal:
        """Remove the plan and return it (or why it cannot run); its id can never be used again.

        A rejected plan is spent too, and keeps answering REJECTED_PLAN. `estop_generation` and
        `caller` as in `peek`: another caller's attempt spends nothing.
        """
        found = self._lookup(plan_id, estop_generation, caller)
        if isinstance(found, PlanRefusal):
            return found
        del self._plans[found.plan_id]
        if found.status == "rejected":
            refusal = self._rejected(found)
            self._retire(found.plan_id, refusal)
            return refusal
        self._retire(found.plan_id, PlanRefusal(
            RefusalCode.USED_PLAN, f"plan {found.plan_id} was already used; a plan runs at most once, plan again"
        ))
        return found

    def _lookup(self, plan_id: object, estop_generation: int | None, caller: str | None
                ) -> StoredPlan | PlanRefusal:
        if not _is_plausible_id(plan_id):
            return PlanRefusal(RefusalCode.UNKNOWN_PLAN, "that is not a plan id this server issued; plan a motion first")
        plan = self._plans.get(plan_id)
        if plan is None:
            retired = self._retired.get(plan_id)
            if retired is not None:
                return retired
            return PlanRefusal(RefusalCode.UNKNOWN_PLAN, f"unknown plan id {plan_id!r}; plan a motion first")
        if self._clock() >= plan.expires_mono:
            del self._plans[plan_id]
            return self._retire(plan_id, self._expired(plan))
        if estop_generation is not None and plan.estop_generation != estop_generation:
            del self._plans[plan_id]
            return self._retire(plan_id, PlanRefusal(
                RefusalCode.INVALIDATED_PLAN, f"plan {plan_id} was made before the latest e-stop latched; plan again once it is safe"
            ))
        if plan.owner is not None and caller != plan.owner:
            return PlanRefusal(
                RefusalCode.NOT_PLAN_OWNER,
                f"plan {plan_id} was made by another client; only the client that planned a motion may execute "
                "it. Plan it yourself; that plan was not touched",
            )
        return plan

    @staticmethod
    def _rejected(plan: StoredPlan) -> PlanRefusal:
        details = "; ".join(f"{v.code.value}: {v.detail}" for v in plan.report.hard[:3])
        more = f" (+{len(plan.report.hard) - 3} more)" if len(plan.report.hard) > 3 else ""
        return PlanRefusal(
            RefusalCode.REJECTED_PLAN,
            f"plan {plan.plan_id} was rejected by the safety envelope and can never run: {details}{more}",
        )

    def _expired(self, plan: StoredPlan) -> PlanRefusal:
        return PlanRefusal(
            RefusalCode.EXPIRED_PLAN,
            f"plan {plan.plan_id} expired at {plan.expires_at_wall} (plans live {self.ttl_s:g} s); plan again",
        )

    def _retire(self, plan_id: str, refusal: PlanRefusal) -> PlanRefusal:
        self._retired[plan_id] = refusal
        self._retired.move_to_end(plan_id)
        while len(self._retired) > RETIRED_MEMORY:
            self._retired.popitem(last=False)
        return refusal

    def _drop_expired(self) -> None:
        """Retire expired plans. One TTL for all and a monotonic clock: plans expire in the order
        they were added, so only the oldest few are ever looked at."""
        now = self._clock()
        while self._plans:
            plan_id, plan = next(iter(self._plans.items()))
            if now < plan.expires_mono:
                return
            self._retire(plan_id, self._expired(self._plans.pop(plan_id)))

    # ------------------------------------------------------------------ checks and invalidation
    def check_start(self, plan: StoredPlan, current_q: object) -> PlanRefusal | None:
        """STALE_PLAN if the arm is no longer where the plan starts (beyond `start_tolerance_rad`)."""
        names = plan.trajectory.joint_names
        try:
            q = np.asarray(current_q, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return PlanRefusal(RefusalCode.STALE_PLAN, f"plan {plan.plan_id}: the current joint state could not be read")
        if q.shape != plan.start.shape:
            return PlanRefusal(
                RefusalCode.STALE_PLAN,
                f"plan {plan.plan_id} is for {plan.start.size} joints but the joint state has {q.size} values",
            )
        drift = np.abs(q - plan.start)
        drift[~np.isfinite(drift)] = np.inf  # an unreadable joint is never "close enough"
        worst = int(np.argmax(drift))
        if drift[worst] <= self.start_tolerance_rad:
            return None
        name = names[worst] if worst < len(names) else f"#{worst}"
        return PlanRefusal(
            RefusalCode.STALE_PLAN,
            f"plan {plan.plan_id} is stale: joint {name} is at {q[worst]:.4f} rad, {drift[worst]:.4f} rad from "
            f"the plan's start {plan.start[worst]:.4f} rad (tolerance {self.start_tolerance_rad:g} rad); "
            "plan again from the current state",
        )

    def invalidate_all(self, reason: object) -> int:
        """Make every outstanding plan unusable (e-stop); returns how many were invalidated."""
        why = flatten_reason(reason, 200) or "no reason given"
        count = len(self._plans)
        for plan_id in list(self._plans):
            del self._plans[plan_id]
            self._retire(plan_id, PlanRefusal(
                RefusalCode.INVALIDATED_PLAN, f"plan {plan_id} was invalidated ({why}); plan again once it is safe"
            ))
        return count
