"""The Backend template's state reads: a published snapshot is returned as is; without one the
read runs under the deadline; a backend that cannot read fails closed."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from armwarden.backends.base import Backend
from armwarden.backends.part_calls import finger_deadline_s
from armwarden.backends.parts import Cameras, Capabilities, Cell, Graph, Gripper
from armwarden.backends.values import CameraImage, ExecutionResult
from armwarden.core.errors import BackendError, BackendTimeout
from armwarden.core.state import GripperState, JointState

NAMES = ("j1", "j2")


class _Probe(Backend):
    """A backend with no hardware: `published` is its snapshot, `_read_joint_state` may hang."""

    name = "probe"

    def __init__(self, published: JointState | None = None, hang_s: float = 0.0, broken: bool = False) -> None:
        super().__init__(NAMES, start_tolerance_rad=0.01)
        self.published, self.hang_s, self.broken = published, hang_s, broken
        self.slow_reads = 0

    async def _open(self) -> None:
        pass

    async def _close(self) -> None:
        pass

    def _latest_joint_state(self) -> JointState | None:
        if self.broken:
            raise BackendError("receive thread died")
        return self.published

    async def _read_joint_state(self) -> JointState:
        self.slow_reads += 1
        await asyncio.sleep(self.hang_s)
        return JointState(NAMES, np.zeros(2), np.zeros(2), 0.0)

    async def _execute(self, trajectory, progress) -> ExecutionResult:  # pragma: no cover - never moves
        raise AssertionError("the read tests never execute")

    async def _stop(self) -> None:
        pass

    def _stop_now(self) -> None:
        pass


def _read(backend: _Probe) -> JointState:
    async def scenario() -> JointState:
        await backend.open()
        try:
            return await backend.read_joint_state()
        finally:
            await backend.close()

    return asyncio.run(scenario())


def test_a_published_snapshot_is_returned_without_the_slow_read():
    snapshot = JointState(NAMES, np.array([0.1, 0.2]), np.zeros(2), 12.5)
    backend = _Probe(published=snapshot)
    assert _read(backend) is snapshot
    assert backend.slow_reads == 0


def test_without_a_snapshot_the_read_runs_under_the_deadline():
    backend = _Probe(hang_s=10.0)
    backend.read_timeout_s = 0.05
    with pytest.raises(TimeoutError):
        _read(backend)
    assert backend.slow_reads == 1


def test_a_backend_whose_snapshot_source_died_fails_the_read():
    with pytest.raises(BackendError, match="receive thread died"):
        _read(_Probe(broken=True))


def test_reads_before_open_are_refused():
    with pytest.raises(BackendError, match="not open"):
        asyncio.run(_Probe().read_joint_state())


# ---------------------------------------------------------------------------- optional-call deadlines
class _SlowFingers(Gripper):
    """A gripper whose move never finishes."""

    def __init__(self, published: GripperState | None = None) -> None:
        self.published = published

    def state(self) -> GripperState:
        if self.published is None:
            raise BackendError("no gripper state published")
        return self.published

    async def move(self, width_m: float, speed_mps: float):
        await asyncio.sleep(3600)
        raise AssertionError("never arrives")

    async def grasp(self, width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m):
        raise AssertionError("not called")

    async def home(self):
        raise AssertionError("not called")

    def stop_now(self) -> None:
        pass


class _SlowGraph(Graph):
    async def describe(self) -> dict[str, list[str]]:
        await asyncio.sleep(3600)
        raise AssertionError("never answers")


class _SlowGripper(_Probe):
    """A probe with a slow gripper and a slow graph whose stops are recorded."""

    def __init__(self, published: GripperState | None = None) -> None:
        super().__init__(published=JointState(NAMES, np.zeros(2), np.zeros(2), 0.0))
        self.stops = 0
        self.fingers, self.ros_graph = _SlowFingers(published), _SlowGraph()
        self.cell = Cell(gripper=self.fingers, graph=self.ros_graph)

    async def _stop(self) -> None:
        self.stops += 1


def _call(backend: _Probe, call):
    async def scenario():
        await backend.open()
        try:
            return await call(backend)
        finally:
            await backend.close()

    return asyncio.run(scenario())


def test_an_actuating_call_past_its_deadline_is_a_backend_timeout_after_a_stop():
    backend = _SlowGripper()
    backend.fingers.timeout_s, backend.fingers.travel_m = 0.05, 0.0
    with pytest.raises(BackendTimeout, match=r"gripper move did not finish within 0\.05 s"):
        _call(backend, lambda b: b.gripper_move(0.01, 0.1))
    assert backend.stops == 2  # the one after the missed deadline, then the one of close()


def test_a_reading_call_past_its_deadline_is_a_backend_timeout_without_a_stop():
    backend = _SlowGripper()
    backend.ros_graph.timeout_s = 0.05
    with pytest.raises(BackendTimeout, match="graph description"):
        _call(backend, lambda b: b.graph())
    assert backend.stops == 1  # only close()'s


def test_a_published_gripper_state_is_returned_as_is():
    published = GripperState(0.04, False, False, 3.0)
    assert _call(_SlowGripper(published), lambda b: b.gripper_state()) is published


def test_a_gripper_with_no_state_published_fails_the_read():
    with pytest.raises(BackendError, match="no gripper state published"):
        _call(_SlowGripper(), lambda b: b.gripper_state())


def test_the_gripper_deadline_grows_with_the_travel_time_at_the_requested_speed():
    assert finger_deadline_s(5.0, 0.08, 0.01) == pytest.approx(13.0)
    assert finger_deadline_s(5.0, 0.08, float("nan")) == 5.0


class _SlowCameraPart(Cameras):
    """A camera that takes `render_s` per frame, plus `setup_s` for its first."""

    def __init__(self, render_s: float, setup_s: float, setup_timeout_s: float) -> None:
        self.render_s, self.setup_s, self.frames = render_s, setup_s, 0
        self.timeout_s, self.setup_timeout_s = 0.2, setup_timeout_s

    @property
    def names(self) -> tuple[str, ...]:
        return ("scene",)

    async def snapshot(self, camera: str) -> CameraImage:
        await asyncio.sleep(self.render_s + (self.setup_s if self.frames == 0 else 0.0))
        self.frames += 1
        return CameraImage(camera, 1, 1, b"", 0.0)

    def set_up(self) -> bool:
        return self.frames > 0


class _SlowCamera(_Probe):
    def __init__(self, render_s: float, setup_s: float, setup_timeout_s: float) -> None:
        super().__init__()
        self.camera = _SlowCameraPart(render_s, setup_s, setup_timeout_s)
        self.cell = Cell(cameras=self.camera)


def test_a_first_snapshot_may_take_the_one_time_setup_on_top_of_the_camera_deadline():
    backend = _SlowCamera(render_s=0.0, setup_s=0.5, setup_timeout_s=60.0)  # setup alone: past the camera's timeout_s

    async def two_snapshots(b: Backend) -> None:
        await b.camera_snapshot("scene")
        await b.camera_snapshot("scene")

    _call(backend, two_snapshots)
    assert backend.camera.frames == 2


def test_a_first_snapshot_past_the_setup_deadline_names_the_setup_and_later_ones_get_the_plain_deadline():
    with pytest.raises(BackendTimeout, match=r"camera 'scene' snapshot \(the first, which sets up rendering\) "
                                             r"did not finish within 0\.5 s"):
        _call(_SlowCamera(render_s=0.0, setup_s=3600.0, setup_timeout_s=0.3), lambda b: b.camera_snapshot("scene"))
    backend = _SlowCamera(render_s=3600.0, setup_s=0.0, setup_timeout_s=60.0)
    backend.camera.frames = 1  # set up already: the plain deadline
    with pytest.raises(BackendTimeout, match=r"camera 'scene' snapshot did not finish within 0\.2 s"):
        _call(backend, lambda b: b.camera_snapshot("scene"))


def test_a_missing_capability_is_refused_before_anything_is_sent():
    with pytest.raises(BackendError, match="has no camera 'wrist'"):
        _call(_Probe(), lambda b: b.camera_snapshot("wrist"))


def test_a_backend_timeout_is_also_a_timeout_error():
    assert issubclass(BackendTimeout, TimeoutError) and issubclass(BackendTimeout, BackendError)


def test_a_backend_class_that_declares_capabilities_beside_its_cell_is_refused():
    with pytest.raises(TypeError, match=r"defines `capabilities`: build its parts into `self\.cell`"):

        class _Declaring(_Probe):
            @property
            def capabilities(self) -> Capabilities:  # the flags of before the cell: tools whose calls fail
                return Capabilities(gripper=True)
