"""`armwarden serve --backend ros2 --backend-config examples/ros2_fr3.yaml` (the bundled FR3
policy) as a real subprocess, against the fake cell as a process of its own
(`python -m tests_ros.cell`), driven by the official MCP SDK client over stdio and over
streamable HTTP on 127.0.0.1. The test reads the cell only through ROS, as any other node would:
its joint states and its trajectory action's goal status topic (`CellWatch`).

One change to both files: wrench and joint-state ages of 0.5 s and 1 s (policy
`force.wrench_timeout_s`, the longest a policy may set; config `wrench.max_age_s`,
`joint_states.max_age_s`) instead of 0.1 s and 0.5 s. The cell is a Python process publishing
from an rclpy timer on a shared 2-core machine: gaps of 0.07–0.38 s between its wrench messages
were measured here under load, and with the bundled 0.1 s the force monitor rightly aborts the
motion (a real FR3 publishes from C++ at 1 kHz)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import anyio
import pytest
import yaml
from mcp import Client, StdioServerParameters
from tests.helpers import HOME, REPO, SRC, records_of, stop_process, text_of
from tests.server.harness import MotionStarted, approve
from tests.server.http_daemon import http_daemon, session

from armwarden.policy import apply_overrides, bundled_policy
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from tests_ros.cell_watch import CellWatch

pytestmark = pytest.mark.anyio

EXAMPLE = REPO / "examples" / "ros2_fr3.yaml"
#: joint 1 by 0.3 rad from home
GOAL = [HOME[0] + 0.3, *HOME[1:]]
#: a slow move (about 10 s of trajectory in real time): long enough to interrupt
SLOW = {"velocity_scaling": 0.03, "acceleration_scaling": 0.03}
#: how far the cell may end from a goal [rad]: it interpolates exactly, JSON rounds
AT_GOAL_RAD = 1e-6


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def ros_env() -> dict[str, str]:
    """The session's environment (its random ROS_DOMAIN_ID and localhost discovery, from
    tests_ros/conftest.py) with this checkout's src and tests importable."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), str(REPO)])}
    env.pop("ARMWARDEN_AUDIT_KEY", None)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and env["ROS_DOMAIN_ID"]
    return env


@pytest.fixture
def cell_process() -> Iterator[subprocess.Popen[str]]:
    """The fake FR3 cell as its own process on the test's domain; SIGTERM after the test."""
    process = subprocess.Popen([sys.executable, "-m", "tests_ros.cell"], cwd=REPO, env=ros_env(),
                               stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    assert "fake FR3 cell ready" in process.stdout.readline()
    yield process
    stop_process(process, 15)


@pytest.fixture
def watch(cell_process: subprocess.Popen[str]) -> Iterator[CellWatch]:
    with CellWatch() as running:
        running.wait_latest("joint_states")
        yield running


def with_overrides(source: Path, target: Path, overrides: dict[str, Any]) -> Path:
    """`source` YAML with dotted-path `overrides`, written to `target`."""
    target.write_text(yaml.safe_dump(apply_overrides(yaml.safe_load(source.read_text()), overrides)))
    return target


@pytest.fixture
def policy(tmp_path: Path) -> Path:
    """The bundled FR3 policy with the longest wrench timeout (module docstring)."""
    return with_overrides(bundled_policy("fr3"), tmp_path / "fr3.yaml", {"force.wrench_timeout_s": MAX_WRENCH_TIMEOUT_S})


@pytest.fixture
def config(tmp_path: Path) -> Path:
    """examples/ros2_fr3.yaml with longer wrench and joint-state ages (module docstring)."""
    return with_overrides(EXAMPLE, tmp_path / "ros2_fr3.yaml",
                          {"wrench.max_age_s": MAX_WRENCH_TIMEOUT_S, "joint_states.max_age_s": 1.0})


def stdio_daemon(audit: Path, policy: Path, config: Path) -> StdioServerParameters:
    return StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--policy", str(policy), "--backend", "ros2", "--backend-config", str(config),
              "--audit-log", str(audit), "--log-level", "WARNING"],
        env=ros_env(),
        cwd=str(REPO),
    )


async def plan_id(client: Client, goal: list[float], **scaling: float) -> str:
    plan = await client.call_tool("plan_to_joints", {"joint_positions": goal, "preview": False, **scaling})
    assert not plan.is_error, text_of(plan)
    assert plan.structured_content["status"] in ("ok", "needs_approval"), plan.structured_content
    return plan.structured_content["plan_id"]


async def state_then_an_approved_move(client: Client, watch: CellWatch) -> None:
    """What an agent does first: read the state (the cell's), plan, execute with a human's approval."""
    state = (await client.call_tool("get_robot_state", {})).structured_content
    assert state["joint_positions"] == pytest.approx(watch.positions(), abs=AT_GOAL_RAD)
    assert state["joint_positions"] == pytest.approx(HOME, abs=AT_GOAL_RAD)

    done = await client.call_tool("execute_plan", {"plan_id": await plan_id(client, GOAL)})

    assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
    assert await anyio.to_thread.run_sync(watch.wait_for_goals, "succeeded") == ["succeeded"]
    await anyio.to_thread.run_sync(watch.wait_at, GOAL, AT_GOAL_RAD)
    after = (await client.call_tool("get_robot_state", {})).structured_content
    assert after["joint_positions"] == pytest.approx(GOAL, abs=AT_GOAL_RAD)


async def test_over_stdio_the_state_is_the_cells_and_an_approved_plan_reaches_its_goal_at_the_cell(tmp_path, watch, policy, config) -> None:
    async with Client(stdio_daemon(tmp_path / "audit.jsonl", policy, config), elicitation_callback=approve()) as client:
        await state_then_an_approved_move(client, watch)


async def test_an_estop_during_execution_cancels_the_goal_and_the_cell_stops(tmp_path, watch, policy, config) -> None:
    moving = MotionStarted()
    outcome: dict[str, Any] = {}
    async with Client(stdio_daemon(tmp_path / "audit.jsonl", policy, config), elicitation_callback=approve()) as client:
        slow = await plan_id(client, GOAL, **SLOW)

        async def execute() -> None:
            outcome["result"] = await client.call_tool("execute_plan", {"plan_id": slow}, progress_callback=moving)
            moving.event.set()  # ended without moving (refused, aborted): the checks below name why

        with anyio.fail_after(60):
            async with anyio.create_task_group() as group:
                group.start_soon(execute)
                await moving.event.wait()
                estop = await client.call_tool("estop", {"reason": "hand in the cell"})
        safety = (await client.call_tool("get_safety_status", {})).structured_content

    assert not estop.is_error and estop.structured_content["estopped"] is True, text_of(estop)
    assert outcome["result"].structured_content["status"] == "aborted", text_of(outcome["result"])
    assert safety["estopped"] is True
    assert await anyio.to_thread.run_sync(watch.wait_for_goals, "canceled") == ["canceled"]
    held = await anyio.to_thread.run_sync(watch.wait_still)
    assert held != pytest.approx(GOAL, abs=1e-3)  # stopped on the way, not at the goal


async def test_a_stdio_client_that_goes_away_mid_motion_has_its_goal_cancelled_at_the_cell(tmp_path, watch, policy, config) -> None:
    audit = tmp_path / "audit.jsonl"
    moving = MotionStarted()
    with anyio.fail_after(60):
        async with anyio.create_task_group() as group:
            async with Client(stdio_daemon(audit, policy, config), elicitation_callback=approve()) as client:
                slow = await plan_id(client, GOAL, **SLOW)

                async def execute() -> None:
                    with contextlib.suppress(Exception):  # the connection goes away under the call
                        await client.call_tool("execute_plan", {"plan_id": slow}, progress_callback=moving)

                group.start_soon(execute)
                await moving.event.wait()
            # the client, and with it the daemon's stdin, is gone while the cell moves

    assert await anyio.to_thread.run_sync(watch.wait_for_goals, "canceled") == ["canceled"]
    held = await anyio.to_thread.run_sync(watch.wait_still)
    assert held != pytest.approx(GOAL, abs=1e-3)
    events = [r["event"] for r in records_of(audit)]  # held the moment the input ended, then shut down
    assert "client_gone" in events and events.index("client_gone") < events.index("shutdown") == len(events) - 1


async def interrupted_mid_motion(daemon: Any, goal: list[float], interrupt: Callable[[], None]) -> str:
    """Over a session of its own: a slow plan to `goal` executes; once it moves, `interrupt()` runs
    and the whole client goes (streams closed, connection dropped). The plan's id."""
    moving = MotionStarted()
    with anyio.fail_after(60):
        async with anyio.create_task_group() as group:
            http, client = session(daemon, daemon.operator_token, "legacy", approve())
            async with http, client:
                slow = await plan_id(client, goal, **SLOW)

                async def execute() -> None:
                    with contextlib.suppress(Exception):  # the daemon may die under the call
                        await client.call_tool("execute_plan", {"plan_id": slow}, progress_callback=moving)

                group.start_soon(execute)
                await moving.event.wait()
                interrupt()
                group.cancel_scope.cancel()
    return slow


async def test_over_http_an_approved_plan_runs_and_a_client_dropped_mid_motion_leaves_the_cell_stopped(
        tmp_path, watch, policy, config) -> None:
    with http_daemon(tmp_path, 1.0, ("--policy", str(policy)), backend="ros2", config=config) as daemon:
        http, client = session(daemon, daemon.operator_token, "legacy", approve())
        async with http, client:
            await state_then_an_approved_move(client, watch)

        back = await interrupted_mid_motion(daemon, HOME, lambda: None)  # only the client goes

        assert await anyio.to_thread.run_sync(watch.wait_for_goals, "succeeded", "canceled") == ["succeeded", "canceled"]
        held = await anyio.to_thread.run_sync(watch.wait_still)
        assert held != pytest.approx(HOME, abs=1e-3)
        assert daemon.process.poll() is None  # the daemon serves on
    interrupted = [r for r in records_of(daemon.audit) if r["event"] == "execution_interrupted" and back in r["detail"]]
    assert [r["outcome"] for r in interrupted] == ["stopped"], interrupted


async def test_a_daemon_killed_mid_motion_has_its_goal_cancelled_by_the_guardian(tmp_path, watch, policy, config) -> None:
    with http_daemon(tmp_path, 1.0, ("--policy", str(policy)), backend="ros2", config=config) as daemon:

        def kill() -> None:  # SIGKILL: no shutdown, no stop of its own
            daemon.process.kill()
            daemon.process.wait()

        await interrupted_mid_motion(daemon, GOAL, kill)

        # nobody but the guardian was left to stop it: without it the goal runs to its end
        assert await anyio.to_thread.run_sync(watch.wait_for_goals, "canceled") == ["canceled"]
        held = await anyio.to_thread.run_sync(watch.wait_still)
        assert held != pytest.approx(GOAL, abs=1e-3)
        assert "the daemon's pipe closed" in daemon.stderr_path.read_text()


async def test_a_daemon_hung_mid_motion_has_its_goal_cancelled_and_latches_when_it_wakes(
        tmp_path, watch, policy, config) -> None:
    with http_daemon(tmp_path, 1.0, ("--policy", str(policy)), backend="ros2", config=config) as daemon:
        moving = MotionStarted()
        outcome: dict[str, Any] = {}
        with anyio.fail_after(60):
            http, client = session(daemon, daemon.operator_token, "legacy", approve())
            async with http, client, anyio.create_task_group() as group:
                slow = await plan_id(client, GOAL, **SLOW)

                async def execute() -> None:
                    outcome["result"] = await client.call_tool("execute_plan", {"plan_id": slow},
                                                               progress_callback=moving)

                group.start_soon(execute)
                await moving.event.wait()
                daemon.process.send_signal(signal.SIGSTOP)  # hung: no beat, no stop, no answer
                try:
                    assert await anyio.to_thread.run_sync(watch.wait_for_goals, "canceled") == ["canceled"]
                finally:
                    daemon.process.send_signal(signal.SIGCONT)
            safety = await read_safety(daemon)

        held = await anyio.to_thread.run_sync(watch.wait_still)
        assert held != pytest.approx(GOAL, abs=1e-3)
        assert outcome["result"].is_error or outcome["result"].structured_content["status"] == "aborted"
        # latched for whatever the daemon found first on waking: the guardian's cancel, or joint
        # states it had not read for the whole stop
        assert safety["estopped"] is True, safety
        assert "the daemon was silent for 0.5 s" in daemon.stderr_path.read_text()


async def read_safety(daemon: Any) -> dict[str, Any]:
    http, client = session(daemon, daemon.operator_token, "legacy")
    async with http, client:
        return (await client.call_tool("get_safety_status", {})).structured_content
