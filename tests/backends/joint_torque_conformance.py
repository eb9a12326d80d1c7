"""Joint-torque conformance: the sign and units of `JointState.efforts` against a known load.

Every backend that declares `capabilities.joint_torques` must publish Pinocchio's τ of
M(q)q̈ + C(q, q̇)q̇ + g(q) = τ + τ_ext (armwarden.core.state): at rest with nothing touching the
arm, efforts == g(q); a force F pushing at a point whose linear Jacobian is J changes them by
−Jᵀ F. A backend's test calls:

- `check_gravity_at_rest(backend, robot, tolerance_nm)`: a still arm reads g(q) of its own pose;
- `check_push(backend, robot, load, tolerance_nm)`: a known push (`Load`: the force, where, and
  the backend's own way to apply and release it) changes the still arm's reading by −Jᵀ F.

Both read settled samples (the arm still over several consecutive reads; `still_rad_s` for a
backend whose velocity encoding is coarse, e.g. CAN's `rest_speed_rad_s`) and compare each with
the model at that sample's own positions, so an arm that yields under the push is judged at the
pose it yielded to. The tolerance is the backend's to justify (its test says why).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.base import Backend
from armwarden.core.state import JointState
from armwarden.robot.model import RobotModel

#: an arm is still when no joint moves faster than this [rad/s] ...
STILL_RAD_S = 2e-3
#: ... over this many consecutive reads
STILL_READS = 10
#: reads are this far apart [s]
READ_PERIOD_S = 0.005


@dataclass(frozen=True)
class Load:
    """A known force `force_base` [N] (base frame) at `point_in_frame` [m] of the model frame
    `frame`, and the backend's own calls that apply and release it."""

    frame: str
    force_base: tuple[float, float, float]
    apply: Callable[[], None]
    release: Callable[[], None]
    point_in_frame: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))


def gravity(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    """g(q) [N·m] of the robot model (a Data of its own: the model's is not the test's to share)."""
    return pin.computeGeneralizedGravity(robot.model, robot.model.createData(), np.asarray(q, dtype=float)).copy()


def push_torque(robot: RobotModel, q: np.ndarray, load: Load) -> np.ndarray:
    """−Jᵀ F [N·m]: what the load adds to the measured joint torques of a still arm at `q`."""
    model = robot.model
    data = model.createData()
    q = np.asarray(q, dtype=float)
    frame_id = robot.frame_id(load.frame)
    jacobian = pin.computeFrameJacobian(model, data, q, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    pin.updateFramePlacements(model, data)
    lever = data.oMf[frame_id].rotation @ np.asarray(load.point_in_frame, dtype=float)
    linear = jacobian[:3] - pin.skew(lever) @ jacobian[3:]
    force_world = data.oMf[robot.frame_id(robot.base_frame)].rotation @ np.asarray(load.force_base, dtype=float)
    return -(linear.T @ force_world)


async def settled_state(backend: Backend, after_stamp: float = -np.inf, timeout_s: float = 20.0,
                        still_rad_s: float = STILL_RAD_S) -> JointState:
    """The first sample newer than `after_stamp` that ends `STILL_READS` still reads in a row
    (no joint faster than `still_rad_s` [rad/s]: a coarse velocity encoding needs more), each
    carrying finite efforts."""
    deadline = time.monotonic() + timeout_s
    still = 0
    while True:
        state = await backend.read_joint_state()
        assert state.efforts is not None, "a backend that declares joint torques published a state without them"
        fresh = state.stamp > after_stamp
        if fresh and float(np.max(np.abs(state.velocities))) < still_rad_s and np.all(np.isfinite(state.efforts)):
            still += 1
            if still >= STILL_READS:
                return state
        else:
            still = 0
        assert time.monotonic() < deadline, f"the arm did not settle with finite efforts within {timeout_s} s"
        await anyio.sleep(READ_PERIOD_S)


async def check_gravity_at_rest(backend: Backend, robot: RobotModel, tolerance_nm: float,
                                still_rad_s: float = STILL_RAD_S) -> JointState:
    """A still arm, nothing touching it, measures g(q) within `tolerance_nm` per joint."""
    assert backend.capabilities.joint_torques
    state = await settled_state(backend, still_rad_s=still_rad_s)
    assert state.efforts is not None
    expected = gravity(robot, state.positions)
    assert np.abs(expected).max() > 5 * tolerance_nm, "pick a pose where gravity loads the arm well above the tolerance"
    np.testing.assert_allclose(state.efforts, expected, rtol=0, atol=tolerance_nm)
    return state


async def check_push(backend: Backend, robot: RobotModel, load: Load, tolerance_nm: float,
                     still_rad_s: float = STILL_RAD_S) -> np.ndarray:
    """A known push changes a still arm's measured torques by −Jᵀ F within `tolerance_nm`;
    released, they come back to g(q). Returns the measured change."""
    assert backend.capabilities.joint_torques
    before = await settled_state(backend, still_rad_s=still_rad_s)
    assert before.efforts is not None
    load.apply()
    try:
        pushed = await settled_state(backend, after_stamp=time.monotonic(), still_rad_s=still_rad_s)
    finally:
        load.release()
    assert pushed.efforts is not None
    expected = push_torque(robot, pushed.positions, load)
    assert np.abs(expected).max() > 5 * tolerance_nm, "pick a push that loads the arm well above the tolerance"
    # each reading less the gravity of its own pose: the arm may have yielded to the push
    change = (pushed.efforts - gravity(robot, pushed.positions)) - (before.efforts - gravity(robot, before.positions))
    np.testing.assert_allclose(change, expected, rtol=0, atol=tolerance_nm)
    after = await settled_state(backend, after_stamp=time.monotonic(), still_rad_s=still_rad_s)
    assert after.efforts is not None
    np.testing.assert_allclose(after.efforts, gravity(robot, after.positions), rtol=0,
                               atol=tolerance_nm + float(np.abs(before.efforts - gravity(robot, before.positions)).max()))
    return change


__all__ = ["Load", "check_gravity_at_rest", "check_push", "gravity", "push_torque", "settled_state"]
