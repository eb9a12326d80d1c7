"""Measured joint torques on the ROS 2 backend against the fake FR3 cell, both over real rclpy: the
cell publishes `JointState.effort` = the FR3 model's inverse dynamics of its motion (g(q) at rest),
a push at a link changes it by −Jᵀ F, and the backend carries it into `JointState.efforts` in
N·m with the right sign when the config declares it (NaN when the cell sends none), None when not.

The expected torques are computed here from the policy's robot model with Pinocchio directly
(`computeGeneralizedGravity`, `computeFrameJacobian`, `rnea`), not through the cell's code."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import AsyncIterator, Callable

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest
from sensor_msgs.msg import JointState as JointStateMsg
from tests.backends.joint_torque_conformance import Load, check_gravity_at_rest, check_push

from armwarden.backends.ros2.backend import Ros2Backend
from armwarden.backends.ros2.state import header_seconds
from armwarden.core.state import JointState
from tests_ros.backend_setup import ROBOT, example_config, example_document, opened
from tests_ros.cell import Cell, CellConfig, _acceleration
from tests_ros.client import DISCOVERY_TIMEOUT_S, RosClient

pytestmark = pytest.mark.anyio

#: generous: the cell and the backend share this process with other suites on 2 cores
DEADLINE_S = 10.0
#: the cell computes in float64 and DDS carries float64: only rounding separates the two sides
EXACT_NM = 1e-6
FOREARM = "fr3_link5"
PUSH_N = np.array([0.0, 30.0, -10.0])  # [N] in the base frame


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def backend_config(efforts: bool):
    # the cell publishes from a thread of this process: ages on a scale its stalls do not reach
    joint_states = {**example_document()["joint_states"], "max_age_s": 1.0, "efforts": efforts}
    return example_config(joint_states=joint_states)


@pytest.fixture
async def declared(cell: Cell) -> AsyncIterator[Ros2Backend]:
    """An open backend whose config declares that the joint states carry efforts."""
    async with opened(backend_config(efforts=True)) as backend:
        yield backend


def gravity(q: np.ndarray) -> np.ndarray:
    return np.array(pin.computeGeneralizedGravity(ROBOT.model, ROBOT.model.createData(), q))


def push_torques(q: np.ndarray, frame: str, force_base: np.ndarray) -> np.ndarray:
    """−Jᵀ F: how a force at `frame`'s origin changes what the joints measure (FR3: base = world)."""
    data = ROBOT.model.createData()
    pin.framesForwardKinematics(ROBOT.model, data, q)
    assert np.allclose(data.oMf[ROBOT.model.getFrameId(ROBOT.base_frame)].homogeneous, np.eye(4))
    jac = pin.computeFrameJacobian(ROBOT.model, data, q, ROBOT.model.getFrameId(frame),
                                   pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    return -jac[:3].T @ force_base


def received_after_now(backend: Ros2Backend, cell: Cell) -> Callable[[], bool]:
    """A probe: whether the backend holds a joint state the cell sent after this call (the cell
    sends every state after a push returns with the push)."""
    sent = cell.last_joint_state_stamp()
    after = -math.inf if sent is None else header_seconds(sent)

    def received() -> bool:
        seen = backend.joint_states.latest_header_s()
        return seen is not None and seen > after

    return received


def wait_until_received(backend: Ros2Backend, cell: Cell) -> None:
    """Block (the backend's executor thread takes the states in) until `received_after_now`."""
    received, deadline = received_after_now(backend, cell), time.monotonic() + DEADLINE_S
    while not received():
        assert time.monotonic() < deadline, "no newer joint state reached the backend"
        time.sleep(0.005)


async def state_sent_after(backend: Ros2Backend, cell: Cell) -> JointState:
    """The backend's joint state from a message the cell sent after this call began."""
    received, deadline = received_after_now(backend, cell), time.monotonic() + DEADLINE_S
    while not received():
        assert time.monotonic() < deadline, "no newer joint state reached the backend"
        await anyio.sleep(0.005)
    return await backend.read_joint_state()


# ---------------------------------------------------------------------------- the backend
async def test_efforts_at_rest_are_the_gravity_torques_in_newton_metres(declared: Ros2Backend) -> None:
    state = await declared.read_joint_state()
    assert state.efforts is not None and np.all(state.velocities == 0.0)
    expected = gravity(state.positions)
    assert np.max(np.abs(expected)) > 10.0  # the FR3 at home holds ≈ 18 N·m at joint 4: not mN·m, not zero
    np.testing.assert_allclose(state.efforts, expected, atol=EXACT_NM, rtol=0)


async def test_a_push_at_the_forearm_changes_the_efforts_by_minus_j_transpose_f(declared: Ros2Backend,
                                                                               cell: Cell) -> None:
    before = await state_sent_after(declared, cell)
    cell.push(FOREARM, PUSH_N)
    pushed = await state_sent_after(declared, cell)
    assert before.efforts is not None and pushed.efforts is not None
    np.testing.assert_array_equal(pushed.positions, before.positions)  # at rest: only the push differs
    change = pushed.efforts - before.efforts
    expected = push_torques(before.positions, FOREARM, PUSH_N)
    assert np.max(np.abs(expected)) > 1.0  # the push loads the joints below the forearm
    np.testing.assert_allclose(change, expected, atol=EXACT_NM, rtol=0)


async def test_a_push_off_the_links_origin_adds_the_moment_of_its_lever(declared: Ros2Backend, cell: Cell) -> None:
    before = await state_sent_after(declared, cell)
    point = np.array([0.0, 0.05, -0.1])  # [m] in the forearm's own frame
    cell.push(FOREARM, PUSH_N, point)
    pushed = await state_sent_after(declared, cell)
    assert before.efforts is not None and pushed.efforts is not None
    q, model = before.positions, ROBOT.model
    data = model.createData()
    frame = model.getFrameId(FOREARM)
    jac = pin.computeFrameJacobian(model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    lever = data.oMf[frame].rotation @ point  # the same force at the origin, plus its moment r × F there
    expected = -(jac[:3].T @ PUSH_N + jac[3:].T @ np.cross(lever, PUSH_N))
    assert np.max(np.abs(expected - push_torques(q, FOREARM, PUSH_N))) > 0.5  # the lever matters
    np.testing.assert_allclose(pushed.efforts - before.efforts, expected, atol=EXACT_NM, rtol=0)


async def test_efforts_return_to_gravity_when_the_push_is_released(declared: Ros2Backend, cell: Cell) -> None:
    cell.push(FOREARM, PUSH_N)
    await state_sent_after(declared, cell)
    cell.release_push()
    state = await state_sent_after(declared, cell)
    assert state.efforts is not None
    np.testing.assert_allclose(state.efforts, gravity(state.positions), atol=EXACT_NM, rtol=0)


async def test_the_backend_declares_joint_torques_when_the_config_does(declared: Ros2Backend) -> None:
    assert declared.capabilities.joint_torques


@pytest.mark.parametrize("cell_config", [CellConfig(efforts=False)])
async def test_declared_efforts_from_a_cell_that_sends_none_are_nan(declared: Ros2Backend) -> None:
    state = await declared.read_joint_state()
    assert state.efforts is not None and len(state.efforts) == len(state.positions)
    assert np.all(np.isnan(state.efforts))


async def test_undeclared_efforts_are_none_and_no_joint_torques_are_declared(cell: Cell) -> None:
    async with opened(backend_config(efforts=False)) as backend:
        assert (await backend.read_joint_state()).efforts is None
        assert not backend.capabilities.joint_torques


# ---------------------------------------------------------------------------- the shared conformance checks
async def test_the_ros2_backend_passes_the_gravity_conformance_check(declared: Ros2Backend) -> None:
    await check_gravity_at_rest(declared, ROBOT, EXACT_NM)


async def test_the_ros2_backend_passes_the_push_conformance_check(declared: Ros2Backend, cell: Cell) -> None:
    force, point = (0.0, 30.0, -10.0), (0.05, 0.0, 0.1)

    def apply() -> None:
        cell.push(FOREARM, force, point)
        wait_until_received(declared, cell)  # a state sent before the push may still be on its way

    def release() -> None:
        cell.release_push()
        wait_until_received(declared, cell)

    await check_push(declared, ROBOT, Load(FOREARM, force, apply, release, point), EXACT_NM)


# ---------------------------------------------------------------------------- the cell
def test_the_cells_efforts_in_motion_are_the_models_inverse_dynamics(client: RosClient) -> None:
    """One segment from rest to rest: the cell publishes the segment's velocity and measures the
    torque of a motion that reaches it at the segment's middle and stops at its end (q̈ = ±2v/T)."""
    names = list(client.wait_latest("joint_states").name)
    start = np.array(client.positions())
    reach, duration = 1.2, 1.0  # joint 1 at 1.2 rad/s: Coriolis and centrifugal torques show
    target = start.copy()
    target[0] += reach
    result = client.send_goal(client.trajectory_goal(names, [target.tolist()], [duration])).get_result_async()
    moving: dict[float, JointStateMsg] = {}
    deadline = time.monotonic() + DEADLINE_S
    while not result.done() and time.monotonic() < deadline:
        msg = client.latest("joint_states")
        if msg is not None and np.any(np.array(msg.velocity) != 0.0):
            moving[header_seconds(msg.header.stamp)] = msg
        time.sleep(0.002)
    data = ROBOT.model.createData()
    halves: dict[float, list[float]] = {1.0: [], -1.0: []}  # speeding up, slowing down: τ beyond gravity
    for msg in moving.values():
        q, qd, effort = (np.array(v, dtype=float) for v in (msg.position, msg.velocity, msg.effort))
        fraction = (q[0] - start[0]) / reach  # of the way, = of the time: the segment is linear
        if abs(fraction - 0.5) < 0.05:
            continue  # the acceleration changes sign at the middle
        sign = 1.0 if fraction < 0.5 else -1.0
        qdd = np.zeros_like(q)
        qdd[0] = sign * 2.0 * reach / duration**2
        np.testing.assert_allclose(effort, pin.rnea(ROBOT.model, data, q, qd, qdd), atol=EXACT_NM, rtol=0)
        halves[sign].append(float(np.max(np.abs(effort - gravity(q)))))
    assert len(halves[1.0]) >= 3 and len(halves[-1.0]) >= 3, f"{len(moving)} moving samples"
    assert min(halves[1.0] + halves[-1.0]) > 0.1  # the motion's own torques, well beyond gravity's


def test_the_cells_acceleration_integrates_to_each_segments_velocity_and_back_to_rest() -> None:
    points = [(0.0, np.array([0.0, 0.0])), (0.4, np.array([0.2, -0.1])), (0.6, np.array([0.5, -0.1])),
              (1.2, np.array([0.5, 0.2]))]
    times = np.linspace(0.0, 1.2, 24_001)
    step = times[1] - times[0]
    velocity = np.cumsum([_acceleration(points, t) for t in times], axis=0) * step  # from rest
    for (t0, q0), (t1, q1) in itertools.pairwise(points):
        middle = round((t0 + t1) / 2 / step)
        np.testing.assert_allclose(velocity[middle], (q1 - q0) / (t1 - t0), atol=5e-3)
    np.testing.assert_allclose(velocity[-1], 0.0, atol=5e-3)


#: the home pose's TCP is 0.487 m above the base: a table 1 cm higher presses on it with 20 N
@pytest.mark.parametrize("cell_config", [CellConfig(table_height_m=0.497)])
def test_the_tables_contact_force_on_the_tcp_shows_in_the_efforts_as_in_the_wrench(client: RosClient) -> None:
    wrench = client.wait_latest("wrench").wrench
    msg = client.wait_latest("joint_states")
    q = np.array(msg.position)
    force = np.array([wrench.force.x, wrench.force.y, wrench.force.z])
    assert force[2] == pytest.approx(2000.0 * (0.497 - ROBOT.tcp_pose(q).position[2]))
    assert force[2] > 5.0
    np.testing.assert_allclose(np.array(msg.effort) - gravity(q), push_torques(q, ROBOT.tcp_frame, force),
                               atol=EXACT_NM, rtol=0)


@pytest.mark.parametrize("cell_config", [CellConfig(torque_noise_nm=0.5, torque_noise_seed=7)])
def test_the_cells_torque_noise_has_the_standard_deviation_asked_for(client: RosClient) -> None:
    deviations: dict[float, np.ndarray] = {}  # header stamp -> effort - g(q), one per joint state
    deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
    while len(deviations) < 40:
        assert time.monotonic() < deadline, f"only {len(deviations)} joint states seen"
        msg = client.latest("joint_states")
        if msg is not None:
            deviations[header_seconds(msg.header.stamp)] = np.array(msg.effort) - gravity(np.array(msg.position))
        time.sleep(0.005)
    noise = np.concatenate(list(deviations.values()))
    assert 0.3 < float(np.std(noise)) < 0.7 and abs(float(np.mean(noise))) < 0.2, (np.std(noise), np.mean(noise))
