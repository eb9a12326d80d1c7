"""The second layers of `execute_plan`, each reached on its own.

Most of the Guard's last checks sit behind an earlier one that already refuses the common case,
which is why a test of the common case never notices when the later check is deleted. Each
scenario here lets the earlier layer pass and makes the change land in the gap right after it,
so only the check under test can refuse:

- an e-stop from the stop channel's thread lands after the plan store handed the plan out: the
  latch gate refuses before `execution_started` is written;
- a stop (or e-stop) lands after the latch gate and the checks after it: the Guard itself refuses
  STOPPED, before the backend is given anything (not only the backend's "stopped before it started");
- the wrench goes away while a human decides: the pre-check saw one, the run-time check refuses;
- the arm already presses on something with more than twice the force limit: the motion runner
  refuses IN_CONTACT before anything moves (from there even a motion away from the contact waits
  for a human).
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from typing import Any

import mcp_types as types
import pytest

from armwarden.guard import Guard
from tests.helpers import records_of, text_of
from tests.server.harness import HOME_TCP_X, arm_harness, plan_down, policy_with

pytestmark = pytest.mark.anyio


def on_another_thread(action: Callable[[], object]) -> None:
    """Run `action` on a thread of its own and wait for it: what the stop channel and SIGUSR1 do,
    off the event loop."""
    worker = threading.Thread(target=action)
    worker.start()
    worker.join()


def estop_from_the_channel(guard: Guard) -> None:
    """The stop channel's e-stop: latch and `emergency_stop_now`, from its own thread."""
    on_another_thread(lambda: guard.stopper.latch_and_stop("operator pressed E-STOP", "stop_channel", lambda _work: None))


def stop_from_the_transport(guard: Guard) -> None:
    """A `stop_motion` request the transport has just read: the arm held at once, from its thread."""
    on_another_thread(guard.stopper.hold_now)


def started_records(arm) -> list[dict[str, Any]]:
    return [r for r in records_of(arm.audit_path) if r["event"] == "execution_started"]


async def test_an_estop_after_the_plan_store_handed_the_plan_out_refuses_before_execution_started(tmp_path,
                                                                                                  monkeypatch) -> None:
    """The plan was valid when the store handed it out (same e-stop generation); the e-stop lands
    right after. Only the latch gate stands between that and an `execution_started` record."""
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        summary = await plan_down(client, z=0.40, status="ok")
        consume = arm.guard.plans.consume

        def consume_then_estop(*args: Any, **kwargs: Any) -> Any:
            plan = consume(*args, **kwargs)
            estop_from_the_channel(arm.guard)
            return plan

        monkeypatch.setattr(arm.guard.plans, "consume", consume_then_estop)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert arm.guard.latch.is_latched
        assert started_records(arm) == []
        assert result.is_error and "[ESTOPPED]" in text_of(result), text_of(result)
        assert arm.actuations == []


@pytest.mark.parametrize("stop", [stop_from_the_transport, estop_from_the_channel], ids=["stop", "estop"])
async def test_a_stop_after_the_last_checks_is_refused_by_the_guard_before_the_hand_over(tmp_path, monkeypatch,
                                                                                         stop) -> None:
    """The stop lands once the force monitor is armed, after the latch gate and the start-state
    check: the Guard's own last check refuses STOPPED, and the backend never receives the
    trajectory (its own "stopped before it started" would be the only layer left)."""
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        summary = await plan_down(client, z=0.40, status="ok")
        force_monitor = arm.guard.runner.force_monitor

        async def arm_the_monitor_then_stop() -> Any:
            monitor = await force_monitor()
            stop(arm.guard)
            return monitor

        monkeypatch.setattr(arm.guard.runner, "force_monitor", arm_the_monitor_then_stop)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[STOPPED]" in text_of(result), text_of(result)
        assert "nothing moved" in text_of(result)
        assert arm.actuations == []


async def test_a_wrench_that_disappears_while_a_human_decides_refuses_at_the_start(tmp_path, monkeypatch) -> None:
    """The pre-check saw a wrench and asked the human; while they decided the wrench estimate went
    away. The force monitor's run-time check refuses NO_WRENCH, and nothing moves."""
    policy = policy_with(**{"approval.mode": "always", "force.source": "sensor"})
    async with arm_harness(tmp_path, policy) as arm:
        async def lose_the_wrench_then_approve(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
            prompts.append(params.message)
            monkeypatch.setattr(arm.fake, "cell", dataclasses.replace(arm.fake.cell, wrench=None))
            return types.ElicitResult(action="accept", content={"approve": True, "operator": "alice"})

        prompts: list[str] = []
        # legacy only: under 2026-07-28 the pre-check runs again in the second round and refuses first
        async with arm.client("legacy", lose_the_wrench_then_approve) as client:
            summary = await plan_down(client, z=0.40)

            result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert len(prompts) == 1
        assert result.is_error and "[NO_WRENCH]" in text_of(result), text_of(result)
        assert arm.actuations == []


async def test_an_arm_already_pressing_with_more_than_twice_the_force_limit_is_refused_in_contact(tmp_path) -> None:
    """The fake's virtual table is 5 mm above the home TCP: the arm rests on it with 100 N, more than
    twice the bundled policy's 30 N. Even a motion straight up, away from the contact, is refused."""
    home_tcp_z = 0.4869  # the bundled policy's home pose (tests.server.harness.HOME_TCP_X's note)
    async with arm_harness(tmp_path, table_height_m=home_tcp_z + 0.005) as arm, arm.client() as client:
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["wrench"]["force"]["z"] > 2 * arm.guard.policy.force.max_contact_force_n, state["wrench"]
        away = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": home_tcp_z + 0.04}})
        assert not away.is_error, text_of(away)

        result = await client.call_tool("execute_plan", {"plan_id": away.structured_content["plan_id"]})

        assert result.is_error and "[IN_CONTACT]" in text_of(result), text_of(result)
        assert "more than twice the limit" in text_of(result)
        assert arm.actuations == []
