"""A backend thread that dies is a latched, audited backend fault (issue 24, item 1), seen through
the official MCP client on the real Guard: `get_safety_status` reports the latched e-stop and the
fault, the audit log has a `backend_fault` record, planning is refused, and `get_robot_state`
names the dead thread instead of serving stale data.

Found by review: a ROS executor thread killed by concurrent camera snapshots left the daemon
serving stale joint states while `get_safety_status` said all was well, and nothing was audited;
the fake's control thread died just as silently.

The evaluation's injected death (`Backend.inject_death`, which `armwarden eval` asks a daemon for
with SIGUSR2) must take the same path: a simulated backend's worker raises, or the CAN emulator
goes silent and the backend's RX timeout finds it; any other backend refuses to die on request.
"""

from __future__ import annotations

from typing import Any

import pytest
from mcp import Client

from armwarden.core.errors import BackendError
from tests.helpers import records_of, text_of, wait_for_record
from tests.server.harness import BACKENDS, HOME_TCP_X, MODES, approve, arm_harness, wait_until

#: harness backends with threads of their own (the minimal backend steps on the event loop)
THREADED = [backend for backend in BACKENDS if backend != "minimal"]


async def safety(client: Client) -> dict[str, Any]:
    result = await client.call_tool("get_safety_status", {})
    assert not result.is_error, text_of(result)
    return result.structured_content


async def assert_a_latched_audited_fault(arm: Any, client: Client, died: str, *, state_names_it: bool = True) -> None:
    """What a dead backend thread must leave, whatever killed it. `state_names_it`: `get_robot_state`
    is refused naming the fault (a dead thread); else it is refused all the same (the CAN backend's
    silent actuators: the state is too old)."""
    await wait_until(lambda: arm.guard.latch.is_latched, timeout_s=10.0, what="the e-stop latched")
    status = await safety(client)
    assert status["estopped"] and status["estop_event"]["source"] == "backend_fault", status
    assert died in status["estop_event"]["reason"], status
    assert any(died in fault for fault in status["faults"]), status
    records = await wait_for_record(arm.audit_path, lambda r: r["event"] == "backend_fault")
    fault = next(r for r in records if r["event"] == "backend_fault")
    assert fault["outcome"] == "latched" and died in fault["detail"], fault
    planned = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.4}})
    assert planned.is_error and "ESTOPPED" in text_of(planned), text_of(planned)
    state = await client.call_tool("get_robot_state", {})
    assert state.is_error and (died in text_of(state) or not state_names_it), text_of(state)


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_the_fake_control_thread_crashing_while_idle_is_a_latched_audited_backend_fault(tmp_path, mode) -> None:
    async with arm_harness(tmp_path) as arm, arm.client(mode, approve()) as client:
        assert not (await safety(client))["estopped"]

        def crash(q: Any) -> Any:
            raise RuntimeError("injected: a bug in the control loop")

        arm.fake._compute_tcp = crash  # the control thread dies on its next tick, as from a bug
        await assert_a_latched_audited_fault(arm, client, "the control thread stopped (RuntimeError: injected: a bug")
        assert arm.actuations == []


@pytest.mark.anyio
@pytest.mark.parametrize("backend", THREADED)
async def test_each_backend_thread_dying_while_idle_is_a_latched_audited_backend_fault(tmp_path, backend) -> None:
    async with arm_harness(tmp_path, backend=backend) as arm, arm.client("legacy", approve()) as client:
        workers = arm.inner.worker_threads
        assert workers, f"the {backend} backend names its threads"
        worker = workers[0]
        arm.inner.inject_worker_failure(worker, RuntimeError(f"injected: the {worker} thread dies"))
        await assert_a_latched_audited_fault(arm, client, f"the {worker} thread stopped (RuntimeError: injected")
        assert arm.actuations == []
        assert records_of(arm.audit_path)  # (the harness verifies the chain on exit)


#: how each simulated backend's injected death shows in its fault (`Backend.inject_death`)
INJECTED_DEATH = {"fake": "the control thread stopped (InjectedBackendDeath: evaluation",
                  "mujoco": "the physics thread stopped (InjectedBackendDeath: evaluation",
                  "can": "no reply for"}  # every emulated actuator silent: the RX timeout


@pytest.mark.anyio
@pytest.mark.parametrize("backend", [backend for backend in BACKENDS if backend in INJECTED_DEATH])
async def test_the_evaluations_injected_death_is_a_latched_audited_backend_fault(tmp_path, backend) -> None:
    async with arm_harness(tmp_path, backend=backend) as arm, arm.client("legacy", approve()) as client:
        what = arm.backend.inject_death()  # through the counting wrapper, as through the daemon's journal
        assert what
        await assert_a_latched_audited_fault(arm, client, INJECTED_DEATH[backend], state_names_it=backend != "can")
        assert arm.actuations == []


@pytest.mark.anyio
@pytest.mark.parametrize("backend", [backend for backend in BACKENDS if backend not in INJECTED_DEATH])
async def test_a_backend_that_may_drive_a_real_arm_refuses_an_injected_death(tmp_path, backend) -> None:
    async with arm_harness(tmp_path, backend=backend) as arm, arm.client("legacy", approve()) as client:
        assert arm.backend.why_no_injected_death() is not None
        with pytest.raises(BackendError, match="may drive a real arm"):
            arm.backend.inject_death()
        assert not (await safety(client))["estopped"]
        assert arm.actuations == []
