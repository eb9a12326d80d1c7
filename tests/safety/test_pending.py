"""The approval board: one-time answers, bound to the plan and the e-stop generation, expiring
with the plan."""

from __future__ import annotations

import numpy as np
import pytest

from armwarden.approval.board import AnswerRefusal, PendingApprovals, PendingRequest
from armwarden.approval.plans import PlanStore, StoredPlan
from armwarden.core.trajectory import JointTrajectory
from armwarden.safety.limits import EnvelopeReport
from tests.helpers import READY, FakeClock

TTL_S = 60.0
NAMES = tuple(f"fr3_joint{i}" for i in range(1, 8))


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock(100.0)


@pytest.fixture
def plan(clock: FakeClock) -> StoredPlan:
    store = PlanStore(TTL_S, 0.01, clock=clock)
    trajectory = JointTrajectory(NAMES, np.array([0.0, 1.0]), np.vstack([READY, READY + 0.1]))
    return store.add(trajectory, EnvelopeReport(violations=()))


@pytest.fixture
def board(clock: FakeClock) -> PendingApprovals:
    return PendingApprovals(clock=clock)


@pytest.fixture
def same_motion(clock: FakeClock) -> tuple[StoredPlan, StoredPlan]:
    """Two plans of the very same motion (one digest), made by two callers."""
    store = PlanStore(TTL_S, 0.01, clock=clock)
    trajectory = JointTrajectory(NAMES, np.array([0.0, 1.0]), np.vstack([READY, READY + 0.1]))
    first = store.add(trajectory, EnvelopeReport(violations=()), owner="token:carol")
    second = store.add(trajectory, EnvelopeReport(violations=()), owner="token:alice")
    assert first.digest == second.digest
    return first, second


def test_offering_the_same_plan_twice_gives_one_request(board: PendingApprovals, plan: StoredPlan) -> None:
    first = board.offer(plan, "prompt", estop_generation=0)
    again = board.offer(plan, "prompt", estop_generation=0)

    assert again is first
    assert board.live(0) == [first]


def test_request_ids_are_long_random_and_distinct(board: PendingApprovals, plan: StoredPlan) -> None:
    a = board.offer(plan, "prompt", estop_generation=0)
    b = board.offer(plan, "prompt", estop_generation=1)

    assert a.request_id != b.request_id
    assert len(a.request_id) >= 32


def test_an_answer_is_taken_once(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)

    first = board.answer(request.request_id, True, "alice", estop_generation=0)
    replay = board.answer(request.request_id, False, "mallory", estop_generation=0)

    assert isinstance(first, PendingRequest) and first.answer == "approved" and first.operator == "alice"
    assert isinstance(replay, AnswerRefusal) and replay.reason == "answered"
    assert request.answer == "approved"


def test_an_answer_after_the_plan_expired_is_refused(board: PendingApprovals, plan: StoredPlan, clock: FakeClock) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)
    clock.advance(TTL_S)

    refused = board.answer(request.request_id, True, "alice", estop_generation=0)

    assert isinstance(refused, AnswerRefusal) and refused.reason == "expired"
    assert board.live(0) == []


def test_an_answer_after_an_estop_is_refused(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)

    refused = board.answer(request.request_id, True, "alice", estop_generation=1)

    assert isinstance(refused, AnswerRefusal) and refused.reason == "stale"
    assert board.live(1) == []


def test_an_unknown_id_is_refused(board: PendingApprovals) -> None:
    refused = board.answer("not-a-request", True, "alice", estop_generation=0)

    assert isinstance(refused, AnswerRefusal) and refused.reason == "unknown"


def test_withdrawing_closes_the_request_and_wakes_its_listener(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)
    woken: list[str | None] = []
    request.listeners.append(lambda r: woken.append(r.answer))

    board.withdraw(plan.plan_id, "the plan was used")

    assert woken == ["withdrawn"]
    assert isinstance(board.answer(request.request_id, True, "alice", 0), AnswerRefusal)


def test_the_link_points_at_the_console_page_of_the_request(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)
    without_console = board.link(request)
    board.console_url = "http://127.0.0.1:8765/console"

    assert without_console is None
    assert board.link(request) == f"http://127.0.0.1:8765/console/approvals/{request.request_id}"


def test_a_round_nonce_is_good_for_one_retry(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)
    nonce = board.start_round(request)

    assert board.spend_round(request, nonce) is True
    assert board.spend_round(request, nonce) is False


def test_a_new_round_voids_the_nonce_of_the_one_before(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)
    earlier = board.start_round(request)
    later = board.start_round(request)

    assert board.spend_round(request, earlier) is False
    assert board.spend_round(request, later) is False  # the failed attempt spent the round too


def test_no_round_no_retry(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)

    assert board.spend_round(request, "anything") is False


def test_the_requesting_token_cannot_approve_its_own_request(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0, requester="alice")

    own = board.answer(request.request_id, True, "alice", estop_generation=0)
    other = board.answer(request.request_id, True, "dana", estop_generation=0)

    assert isinstance(own, AnswerRefusal) and own.reason == "self_approval"
    assert isinstance(other, PendingRequest) and other.operator == "dana" and not other.self_approved


def test_the_requesting_token_may_decline_its_own_request(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0, requester="alice")

    declined = board.answer(request.request_id, False, "alice", estop_generation=0)

    assert isinstance(declined, PendingRequest) and declined.answer == "declined"


def test_self_approval_when_allowed_is_marked(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0, requester="alice")

    own = board.answer(request.request_id, True, "alice", estop_generation=0, allow_self_approval=True)

    assert isinstance(own, PendingRequest) and own.answer == "approved" and own.self_approved


def test_a_request_without_a_token_may_be_approved_by_any_operator(board: PendingApprovals, plan: StoredPlan) -> None:
    request = board.offer(plan, "prompt", estop_generation=0)  # e.g. a stdio client: no token to compare

    answered = board.answer(request.request_id, True, "alice", estop_generation=0)

    assert isinstance(answered, PendingRequest) and not answered.self_approved


def test_two_callers_of_the_same_motion_get_a_request_each(board: PendingApprovals,
                                                           same_motion: tuple[StoredPlan, StoredPlan]) -> None:
    carols, alices = same_motion
    carol = board.offer(carols, "prompt", estop_generation=0, requester="carol")
    alice = board.offer(alices, "prompt", estop_generation=0, requester="alice")

    assert alice is not carol
    assert (carol.plan_id, carol.requester) == (carols.plan_id, "carol")
    assert (alice.plan_id, alice.requester) == (alices.plan_id, "alice")


def test_a_caller_cannot_approve_its_own_request_for_a_motion_another_caller_asked_for_too(
        board: PendingApprovals, same_motion: tuple[StoredPlan, StoredPlan]) -> None:
    carols, alices = same_motion
    board.offer(carols, "prompt", estop_generation=0, requester="carol")
    alice = board.offer(alices, "prompt", estop_generation=0, requester="alice")

    own = board.answer(alice.request_id, True, "alice", estop_generation=0)

    assert isinstance(own, AnswerRefusal) and own.reason == "self_approval"


def test_using_one_plan_leaves_the_request_of_another_plan_of_the_same_motion_open(
        board: PendingApprovals, same_motion: tuple[StoredPlan, StoredPlan]) -> None:
    carols, alices = same_motion
    carol = board.offer(carols, "prompt", estop_generation=0, requester="carol")
    board.offer(alices, "prompt", estop_generation=0, requester="alice")

    board.withdraw(alices.plan_id, "the plan was used")

    assert carol.answer is None and board.open_for(carols.plan_id, 0) is carol
    assert board.open_for(alices.plan_id, 0) is None
