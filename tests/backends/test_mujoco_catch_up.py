"""MuJoCo's physics thread catching up after a stall keeps a sample every 5 ms of simulated time
on the way. The observer's interval bounds are on the arm's time, so at the harness's speedup 4 a
30 ms stall is 120 ms of motion: measured once at the end, it ended a free motion as a lost
reading (found by review)."""

from __future__ import annotations

import time

import anyio
import numpy as np
import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

pytest.importorskip("mujoco")

from armwarden.backends.mujoco.backend import MujocoBackend, create_backend
from armwarden.backends.mujoco.config import Config
from armwarden.policy import load_policy
from armwarden.policy.loading import bundled_policy
from armwarden.robot import build_robot
from armwarden.safety.contact_source import JointTorqueContact
from tests.backends.contract import straight_line
from tests.helpers import run_opened
from tests.safety.test_joint_torque_monitor import mon_observer

POLICY = load_policy(bundled_policy("fr3"))
ROBOT = build_robot(POLICY)
#: the server harness's MuJoCo speedup (tests/server/harness.py)
SPEEDUP = 4.0


def test_a_30_ms_stall_of_the_physics_thread_mid_motion_is_not_a_lost_reading() -> None:
    home = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    goal = home + np.array([0.3, 0.2, 0.0, 0.2, 0.0, 0.0, 0.0])

    async def scenario(backend: MujocoBackend) -> tuple[int, bool]:
        step = backend.arm.step
        stalls = 0

        def stalling(setpoint, now_wall, speedup):  # type: ignore[no-untyped-def]
            nonlocal stalls
            moving = float(np.max(np.abs(backend.arm.measured.velocities))) > 0.1
            if setpoint.following and stalls == 0 and moving:
                stalls += 1
                time.sleep(0.03)
                now_wall = time.perf_counter()
            return step(setpoint, now_wall, speedup)

        backend.arm.step = stalling  # type: ignore[method-assign]
        contact = JointTorqueContact(backend.read_joint_states_since, mon_observer(ROBOT), ROBOT.joint_names,
                                     time_scale=backend.capabilities.time_scale,
                                     max_unobserved_s=POLICY.force.wrench_timeout_s)
        await contact.read()
        finite = True
        async with anyio.create_task_group() as group:
            done = anyio.Event()

            async def move() -> None:
                await backend.execute(straight_line(ROBOT.joint_names, home, goal, 1.0))
                done.set()

            group.start_soon(move)
            while not done.is_set():
                estimate = await contact.read()
                finite = finite and estimate is not None and bool(np.all(np.isfinite(estimate.force)))
                await anyio.sleep(0.005)
        return stalls, finite

    stalls, finite = run_opened(lambda: create_backend(ROBOT, POLICY, Config(speedup=SPEEDUP)), scenario)
    assert stalls == 1 and finite


def test_a_tick_that_steps_a_stall_keeps_a_few_samples_under_20_ms_apart_on_the_way() -> None:
    """Deterministic: one call of the physics over 30 ms of wall time at speedup 4 (120 steps of
    1 ms) keeps at most 8 samples on the way, evenly apart (14 ms of simulated time: under the
    observer's 20 ms), oldest first, before the tick's own."""
    backend = create_backend(ROBOT, POLICY, Config(speedup=SPEEDUP))
    arm = backend.arm
    arm.start(100.0)
    arm.step(backend.servo.latest, 100.03, SPEEDUP)
    stamps = np.array([s.stamp for s in (*arm.catch_up, arm.measured)])
    sim = np.array([s.sim_s for s in (*arm.catch_up, arm.measured)])
    assert len(arm.catch_up) == 8  # 120 steps: a sample after every 14th, the last one is `measured`
    np.testing.assert_allclose(np.diff(sim)[:-1], 0.014, atol=1e-9)
    np.testing.assert_allclose(np.diff(stamps)[:-1], 0.014 / SPEEDUP, atol=1e-9)
    assert 0.0 < np.diff(sim)[-1] <= 0.014 + 1e-9  # then the tick's own sample
