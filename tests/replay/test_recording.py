"""What each planning call's audit record carries for a replay (`extra.replay`): the exact start
joint state the Guard planned from, the request as the planner got it (exactly invertible), the
digest of the policy in force and the planner settings, including the scalings after the caps."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from armwarden.guard.planning import decode_request, encode_request
from armwarden.planning.planners import PoseTarget
from armwarden.policy import bundled_policy, load_policy, policy_digest
from tests.helpers import HOME, records_of
from tests.replay.session import SessionLog


def plan_records(session_log: SessionLog) -> dict[str, dict]:
    """The plan_* records of the session by step name (steps that planned something)."""
    by_id = {r["extra"]["result"]["plan_id"]: r for r in records_of(session_log.path)
             if r["tool"] and r["tool"].startswith("plan_") and (r["extra"] or {}).get("result")}
    return {step: by_id[plan_id] for step, plan_id in session_log.plan_ids.items() if plan_id in by_id}


def test_each_plan_record_carries_the_exact_start_state_it_was_planned_from(session_log) -> None:
    records = plan_records(session_log)
    assert records["to_a"]["extra"]["replay"]["start_q"] == HOME  # the fake arm starts at the policy's home
    assert records["big_step"]["extra"]["replay"]["start_q"] == HOME  # back home after back_home ran


def test_each_plan_record_carries_the_digest_of_the_policy_in_force(session_log) -> None:
    digest = policy_digest(load_policy(bundled_policy("fr3")))
    assert {r["extra"]["replay"]["policy_digest"] for r in plan_records(session_log).values()} == {digest}


def test_the_planner_settings_record_the_scaling_after_the_cap_and_the_search_seed(session_log) -> None:
    fast = plan_records(session_log)["fast"]["extra"]["replay"]
    assert fast["request"]["velocity_scaling"] == 0.5  # asked
    assert fast["planner"]["velocity_scaling"] == 0.3  # used: the policy's cap
    assert fast["planner"]["planning_time_s"] == 0.5 and fast["planner"]["detours"] is True
    assert isinstance(fast["planner"]["seed"], int)


def test_a_plan_refused_before_planning_carries_no_replay_data(session_log) -> None:
    refused = [r for r in records_of(session_log.path) if r["tool"] == "plan_to_joints" and r["outcome"] == "invalid"]
    assert len(refused) == 1 and "replay" not in (refused[0]["extra"] or {})


def test_policy_digest_ignores_formatting_but_not_values(tmp_path) -> None:
    text = bundled_policy("fr3").read_text(encoding="utf-8")
    reformatted = tmp_path / "same.yaml"
    reformatted.write_text("# another comment\n" + text.replace("max_cartesian_step_m: 0.5 ", "max_cartesian_step_m: 0.50"),
                           encoding="utf-8")
    changed = tmp_path / "changed.yaml"
    changed.write_text(text.replace("max_cartesian_step_m: 0.5 ", "max_cartesian_step_m: 0.4 "), encoding="utf-8")

    original = policy_digest(load_policy(bundled_policy("fr3")))
    assert policy_digest(load_policy(reformatted)) == original
    assert policy_digest(load_policy(changed)) != original


finite = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False)
rotations = st.none() | st.lists(finite, min_size=9, max_size=9)


@given(position=st.lists(finite, min_size=3, max_size=3), rotation=rotations,
       scaling=st.none() | st.floats(min_value=0.001, max_value=1.0))
def test_a_recorded_pose_request_decodes_to_exactly_what_the_planner_received(position, rotation, scaling) -> None:
    target = PoseTarget(np.array(position), None if rotation is None else np.array(rotation).reshape(3, 3))
    request = {"target": target, "velocity_scaling": scaling, "acceleration_scaling": None}

    decoded = decode_request("pose", json.loads(json.dumps(encode_request("pose", request))))

    assert decoded["velocity_scaling"] == scaling
    assert np.array_equal(decoded["target"].position, target.position)
    assert (decoded["target"].rotation is None) == (target.rotation is None)
    if target.rotation is not None:
        assert np.array_equal(decoded["target"].rotation, target.rotation)
