"""Plan store: random single-use ids, TTL, start binding, rejection, invalidation, eviction."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.approval.plans import RETIRED_MEMORY, PlanRefusal, PlanStore, StoredPlan
from armwarden.core.errors import ConfigurationError, RefusalCode
from armwarden.core.trajectory import JointTrajectory
from armwarden.policy import Policy
from armwarden.safety.limits import EnvelopeReport
from armwarden.safety.violations import Code, Violation
from tests.helpers import FakeClock

JOINTS = ("j1", "j2", "j3")
START = np.array([0.1, -0.2, 0.3])
OK = EnvelopeReport(violations=())
SOFT = EnvelopeReport(violations=(Violation(Code.NEAR_JOINT_LIMIT, "j2 within 0.03 rad of its limit"),))
HARD = EnvelopeReport(violations=(Violation(Code.KEEP_OUT, "link fr3_link7 enters keep-out 'table'"),))


def trajectory(start: np.ndarray = START) -> JointTrajectory:
    return JointTrajectory(JOINTS, np.array([0.0, 1.0]), np.vstack([start, start + 0.1]))


def make_store(**kwargs) -> tuple[PlanStore, FakeClock]:
    clock = FakeClock(100.0)
    kwargs.setdefault("ttl_s", 30.0)
    kwargs.setdefault("start_tolerance_rad", 0.01)
    return PlanStore(clock=clock, wall_clock=lambda: 1_700_000_000.0, **kwargs), clock


def refusal_code(result: StoredPlan | PlanRefusal) -> str:
    assert isinstance(result, PlanRefusal), f"expected a refusal, got {result!r}"
    return result.code


def test_add_returns_a_plan_with_random_id_digest_start_and_expiry() -> None:
    store, _clock = make_store()
    traj = trajectory()
    plan = store.add(traj, OK, estop_generation=4, meta={"summary": "move"})
    assert re.fullmatch(r"plan_[A-Za-z0-9_-]{22}", plan.plan_id)
    assert plan.digest == traj.digest and plan.trajectory is traj and plan.report is OK
    assert plan.status == "ok" and plan.estop_generation == 4 and plan.meta["summary"] == "move"
    np.testing.assert_array_equal(plan.start, START)
    assert not plan.start.flags.writeable
    assert plan.created_mono == 100.0 and plan.expires_mono == 130.0
    assert plan.expires_at_wall == "2023-11-14T22:13:50.000Z"


def test_status_follows_the_report_unless_given() -> None:
    store, _ = make_store()
    assert store.add(trajectory(), SOFT).status == "needs_approval"
    assert store.add(trajectory(), HARD).status == "rejected"
    assert store.add(trajectory(), OK, status="needs_approval").status == "needs_approval"


def test_a_plan_with_hard_violations_can_never_be_stored_as_runnable() -> None:
    store, _ = make_store()
    for status in ("ok", "needs_approval"):
        with pytest.raises(ValueError, match="hard violations"):
            store.add(trajectory(), HARD, status=status)


def test_meta_is_a_read_only_copy() -> None:
    store, _ = make_store()
    meta = {"k": 1}
    plan = store.add(trajectory(), OK, meta=meta)
    meta["k"] = 2
    assert plan.meta["k"] == 1
    with pytest.raises(TypeError):
        plan.meta["k"] = 3  # type: ignore[index]


def test_peek_does_not_consume_and_can_be_repeated() -> None:
    store, _ = make_store()
    plan = store.add(trajectory(), OK)
    assert store.peek(plan.plan_id) is plan
    assert store.peek(plan.plan_id) is plan
    assert store.consume(plan.plan_id) is plan


def test_consume_is_single_use_and_replay_says_already_used() -> None:
    store, _ = make_store()
    plan = store.add(trajectory(), OK)
    assert store.consume(plan.plan_id) is plan
    replay = store.consume(plan.plan_id)
    assert refusal_code(replay) == "USED_PLAN" and "already used" in replay.message
    assert refusal_code(store.peek(plan.plan_id)) == "USED_PLAN"


def test_unknown_id_is_refused() -> None:
    store, _ = make_store()
    result = store.peek("plan_doesnotexist")
    assert refusal_code(result) == "UNKNOWN_PLAN" and "plan_doesnotexist" in result.message


@pytest.mark.parametrize("bad", ["", "x" * 65, "plan_\n", "plan_\x00", "plan_é", None, 42, b"plan_", ["plan_x"]])
def test_implausible_ids_are_unknown_and_not_echoed(bad: object) -> None:
    store, _ = make_store()
    for lookup in (store.peek, store.consume):
        result = lookup(bad)
        assert refusal_code(result) == "UNKNOWN_PLAN"
        assert (not isinstance(bad, str) or not bad) or bad not in result.message


def test_huge_id_is_not_echoed() -> None:
    store, _ = make_store()
    result = store.consume("A" * 1_000_000)
    assert refusal_code(result) == "UNKNOWN_PLAN" and len(result.message) < 200


def test_plan_expires_after_ttl_on_the_monotonic_clock() -> None:
    store, clock = make_store(ttl_s=30.0)
    plan = store.add(trajectory(), OK)
    clock.now += 29.999
    assert store.peek(plan.plan_id) is plan
    clock.now += 0.001
    expired = store.consume(plan.plan_id)
    assert refusal_code(expired) == "EXPIRED_PLAN" and "expired" in expired.message
    assert refusal_code(store.consume(plan.plan_id)) == "EXPIRED_PLAN"  # still explained on replay


def test_expired_plans_are_dropped_when_new_ones_are_added() -> None:
    store, clock = make_store(ttl_s=5.0)
    old = store.add(trajectory(), OK)
    clock.now += 10
    store.add(trajectory(), OK)
    assert len(store) == 1
    assert refusal_code(store.peek(old.plan_id)) == "EXPIRED_PLAN"


def test_rejected_plan_is_stored_and_answers_rejected_with_the_reason() -> None:
    store, _ = make_store()
    plan = store.add(trajectory(), HARD)
    peeked = store.peek(plan.plan_id)
    assert refusal_code(peeked) == "REJECTED_PLAN" and "keep-out" in peeked.message
    assert refusal_code(store.peek(plan.plan_id)) == "REJECTED_PLAN"
    assert refusal_code(store.consume(plan.plan_id)) == "REJECTED_PLAN"
    assert refusal_code(store.consume(plan.plan_id)) == "REJECTED_PLAN"  # spent, still explained
    assert len(store) == 0


def test_invalidate_all_makes_every_outstanding_plan_unusable() -> None:
    store, _ = make_store()
    plans = [store.add(trajectory(), OK) for _ in range(3)]
    used = plans.pop()
    store.consume(used.plan_id)
    assert store.invalidate_all("e-stop #2:\nforce limit") == 2
    for plan in plans:
        refused = store.consume(plan.plan_id)
        assert refusal_code(refused) == "INVALIDATED_PLAN"
        assert "e-stop #2: force limit" in refused.message
        assert refusal_code(store.peek(plan.plan_id)) == "INVALIDATED_PLAN"
    assert refusal_code(store.peek(used.plan_id)) == "USED_PLAN"
    assert len(store) == 0


def test_plans_added_after_invalidation_work() -> None:
    store, _ = make_store()
    store.invalidate_all("estop")
    plan = store.add(trajectory(), OK)
    assert store.consume(plan.plan_id) is plan


def test_oldest_plans_are_evicted_beyond_max_plans() -> None:
    store, _ = make_store(max_plans=3)
    plans = [store.add(trajectory(), OK) for _ in range(5)]
    assert len(store) == 3
    for evicted in plans[:2]:
        refused = store.peek(evicted.plan_id)
        assert refusal_code(refused) == "EXPIRED_PLAN" and "discarded" in refused.message
    assert all(store.peek(p.plan_id) is p for p in plans[2:])


def test_check_start_accepts_drift_within_tolerance() -> None:
    store, _ = make_store(start_tolerance_rad=0.01)
    plan = store.add(trajectory(), OK)
    assert store.check_start(plan, START + np.array([0.0099, -0.0099, 0.0])) is None


def test_check_start_names_the_drifted_joint_and_the_drift() -> None:
    store, _ = make_store(start_tolerance_rad=0.01)
    plan = store.add(trajectory(), OK)
    stale = store.check_start(plan, START + np.array([0.005, 0.0, 0.05]))
    assert refusal_code(stale) == "STALE_PLAN"
    assert "joint j3" in stale.message and "0.0500 rad" in stale.message and "0.01 rad" in stale.message


@pytest.mark.parametrize("q", [[0.1, -0.2], [0.1, -0.2, float("nan")], "not a state", None])
def test_check_start_refuses_malformed_or_unreadable_state(q: object) -> None:
    store, _ = make_store()
    plan = store.add(trajectory(), OK)
    assert refusal_code(store.check_start(plan, q)) == "STALE_PLAN"


def test_replays_are_remembered_up_to_a_bound() -> None:
    store, _ = make_store(max_plans=RETIRED_MEMORY + 10)
    first = store.add(trajectory(), OK)
    store.consume(first.plan_id)
    for _ in range(RETIRED_MEMORY):
        store.consume(store.add(trajectory(), OK).plan_id)
    # the memory is bounded: the oldest spent id is forgotten, but it is still refused
    assert refusal_code(store.consume(first.plan_id)) == "UNKNOWN_PLAN"


def test_from_policy_uses_ttl_and_start_tolerance(fr3_policy: Policy) -> None:
    store = PlanStore.from_policy(fr3_policy)
    assert store.ttl_s == fr3_policy.motion.plan_ttl_s
    assert store.start_tolerance_rad == fr3_policy.motion.start_tolerance_rad


@pytest.mark.parametrize(
    "kwargs", [{"ttl_s": 0}, {"ttl_s": float("inf")}, {"start_tolerance_rad": -1.0}, {"max_plans": 0}]
)
def test_rejects_invalid_settings(kwargs: dict) -> None:
    with pytest.raises(ConfigurationError):
        make_store(**kwargs)


def test_malformed_trajectory_can_still_be_stored_as_rejected() -> None:
    store, _ = make_store()
    empty = JointTrajectory(JOINTS, np.zeros(0), np.zeros((0, 3)))
    malformed = EnvelopeReport(violations=(Violation(Code.MALFORMED, "no waypoints"),))
    plan = store.add(empty, malformed)
    assert plan.status == "rejected"
    assert refusal_code(store.consume(plan.plan_id)) == "REJECTED_PLAN"


@settings(max_examples=25, deadline=None)
@given(n=st.integers(min_value=1, max_value=400), replay_order=st.randoms(use_true_random=False))
def test_plan_ids_never_collide_and_every_replay_is_refused(n: int, replay_order) -> None:
    store, _ = make_store(max_plans=1000)
    plans = [store.add(trajectory(), OK) for _ in range(n)]
    ids = [p.plan_id for p in plans]
    assert len(set(ids)) == n
    replay_order.shuffle(plans)
    for plan in plans:
        assert store.consume(plan.plan_id) is plan
    for plan_id in ids:
        assert refusal_code(store.consume(plan_id)) == "USED_PLAN"
        assert refusal_code(store.peek(plan_id)) == "USED_PLAN"


@settings(max_examples=200, deadline=None)
@given(plan_id=st.one_of(st.text(max_size=200), st.binary(max_size=80), st.none(), st.integers()))
def test_any_id_input_is_answered_with_a_refusal_not_an_exception(plan_id: object) -> None:
    store, _ = make_store()
    store.add(trajectory(), OK)
    result = store.consume(plan_id)
    assert isinstance(result, PlanRefusal) and result.code == "UNKNOWN_PLAN"
    assert len(result.message) < 200


# ------------------------------------------------------------------ owner
def test_only_the_owner_finds_its_plan_and_another_caller_spends_nothing() -> None:
    store, _ = make_store()
    plan = store.add(trajectory(), OK, owner="session:alice")
    assert refusal_code(store.peek(plan.plan_id, caller="session:bob")) == RefusalCode.NOT_PLAN_OWNER
    assert refusal_code(store.consume(plan.plan_id, caller="session:bob")) == "NOT_PLAN_OWNER"
    assert refusal_code(store.consume(plan.plan_id)) == "NOT_PLAN_OWNER"  # no caller is not the owner either
    assert store.peek(plan.plan_id, caller="session:alice") is plan
    assert store.consume(plan.plan_id, caller="session:alice") is plan
    assert refusal_code(store.consume(plan.plan_id, caller="session:alice")) == "USED_PLAN"


def test_a_plan_without_an_owner_runs_for_any_caller() -> None:
    store, _ = make_store()
    plan = store.add(trajectory(), OK)
    assert plan.owner is None
    assert store.consume(plan.plan_id, caller="session:bob") is plan


def test_refusal_codes_are_the_enum_and_compare_as_their_wire_strings() -> None:
    store, _ = make_store()
    refused = store.peek("plan_nobody_made_this")
    assert isinstance(refused, PlanRefusal) and refused.code is RefusalCode.UNKNOWN_PLAN
    assert refused.code == "UNKNOWN_PLAN" and f"[{refused.code}]" == "[UNKNOWN_PLAN]"
