"""The ROS 2 backend's optional parts against the cell: cameras (raw and compressed, only
configured names), gripper, controllers (allowlisted only), error recovery, graph, transforms —
and each one absent from the capabilities when its config section is."""

from __future__ import annotations

import io
import time

import anyio
import numpy as np
import pytest
from PIL import Image

from armwarden.backends.parts import Capabilities
from armwarden.core.errors import BackendError
from armwarden.guard.readings import Readings
from tests_ros.backend_setup import POLICY, ROBOT, build_backend, example_config, example_document, opened
from tests_ros.cell import Cell, CellConfig

pytestmark = pytest.mark.anyio

CAMERAS = {
    "scene": {"topic": "/scene_camera/color/image_raw", "kind": "image", "timeout_s": 2.0},
    "scene_png": {"topic": "/scene_camera/color/image_raw/compressed", "kind": "compressed", "timeout_s": 2.0},
    "silent": {"topic": "/no_camera/image_raw", "kind": "image", "timeout_s": 0.3},
}


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def pixels(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as image:
        return np.asarray(image.convert("RGB"))


# ---------------------------------------------------------------------------- cameras
@pytest.mark.parametrize("camera", ["scene", "scene_png"])
async def test_a_snapshot_is_the_cells_picture_as_png(cell: Cell, camera: str) -> None:
    async with opened(example_config(cameras=CAMERAS)) as backend:
        image = await backend.camera_snapshot(camera)
    assert (image.camera, image.width, image.height) == (camera, 64, 48)
    assert np.array_equal(pixels(image.png), cell.render_image(cell.positions()))


async def test_a_camera_that_sends_nothing_times_out_naming_its_topic(cell: Cell) -> None:
    async with opened(example_config(cameras=CAMERAS)) as backend:
        with pytest.raises(BackendError, match=r"camera 'silent': no image on /no_camera/image_raw within 0\.3 s"):
            await backend.camera_snapshot("silent")


async def test_only_configured_cameras_are_served(cell: Cell) -> None:
    async with opened() as backend:
        assert backend.capabilities.cameras == ("scene",)
        with pytest.raises(BackendError, match="has no camera 'wrist'"):
            await backend.camera_snapshot("wrist")


# ---------------------------------------------------------------------------- gripper
async def test_gripper_move_reaches_the_width_and_the_state_follows_the_finger_joints(cell: Cell) -> None:
    async with opened() as backend:
        result = await backend.gripper_move(0.03, 0.1)
        assert result.success and result.width_m == pytest.approx(0.03)
        state = await backend.gripper_state()
    assert state is not None and state.width_m == pytest.approx(0.03) and cell.gripper_width() == pytest.approx(0.03)


async def test_a_grasp_within_the_tolerances_reports_grasped(cell: Cell) -> None:
    async with opened() as backend:
        result = await backend.gripper_grasp(0.05, 20.0, 0.1, 0.005, 0.005)
    assert result.success and result.is_grasped and result.width_m == pytest.approx(0.05)


async def test_a_grasp_force_above_the_configured_effort_is_refused_before_sending(cell: Cell) -> None:
    async with opened() as backend:
        with pytest.raises(BackendError, match=r"gripper grasp force 100\.0 N outside \(0, 70\.0\] N"):
            await backend.gripper_grasp(0.05, 100.0, 0.1, 0.005, 0.005)
    assert cell.counters().gripper_goals == 0


# ---------------------------------------------------------------------------- controllers and recovery
async def test_controllers_are_listed_from_the_controller_manager(cell: Cell) -> None:
    async with opened() as backend:
        controllers = {c.name: c.state for c in await backend.list_controllers()}
    assert controllers == cell.controller_states()


async def test_an_allowlisted_switch_reaches_the_controller_manager(cell: Cell) -> None:
    async with opened() as backend:
        await backend.switch_controllers(["joint_impedance_controller"], ["fr3_arm_controller"])
    assert cell.controller_states()["joint_impedance_controller"] == "active"
    assert cell.controller_states()["fr3_arm_controller"] == "inactive"


async def test_a_controller_outside_the_allowlist_is_refused_before_any_call(cell: Cell) -> None:
    async with opened() as backend:
        with pytest.raises(BackendError, match=r"joint_state_broadcaster are not in the ros2 backend's allowlist"):
            await backend.switch_controllers([], ["joint_state_broadcaster"])
    assert cell.counters().switch_calls == 0


async def test_error_recovery_calls_the_trigger_service(cell: Cell) -> None:
    async with opened() as backend:
        await backend.error_recovery()
    assert cell.counters().error_recoveries == 1


@pytest.mark.parametrize("cell_config", [CellConfig(error_recovery_succeeds=False)])
async def test_a_failed_error_recovery_is_an_error_with_the_services_message(cell: Cell) -> None:
    async with opened() as backend:
        with pytest.raises(BackendError, match="error recovery failed: fake cell: reflex still active"):
            await backend.error_recovery()


# ---------------------------------------------------------------------------- graph and frames
EXPECTED_GRAPH = {
    "nodes": "/fake_fr3_cell",
    "topics": "/joint_states [sensor_msgs/msg/JointState]",
    "services": "/controller_manager/list_controllers [controller_manager_msgs/srv/ListControllers]",
    "actions": "/fr3_arm_controller/follow_joint_trajectory [control_msgs/action/FollowJointTrajectory]",
}


async def discovered_graph(backend) -> dict[str, list[str]]:
    """Node names and each kind of endpoint are discovered separately, and after the topics the
    backend waited for on open, so the first snapshot can lack some; poll until it holds them
    all or ten seconds pass, then let the assertions say what is missing."""
    graph = await backend.graph()
    with anyio.move_on_after(10.0):
        while not all(entry in graph[kind] for kind, entry in EXPECTED_GRAPH.items()):
            await anyio.sleep(0.05)
            graph = await backend.graph()
    return graph


async def test_the_graph_names_the_cells_node_topics_services_and_actions_with_types(cell: Cell) -> None:
    async with opened() as backend:
        graph = await discovered_graph(backend)
    assert "/fake_fr3_cell" in graph["nodes"] and "/armwarden" in graph["nodes"]
    for kind, entry in EXPECTED_GRAPH.items():
        assert entry in graph[kind]
    assert not any("/_action/" in name for name in graph["topics"] + graph["services"])


async def wait_for_frame(backend, frame: str) -> None:
    """/tf_static is latched, but discovery takes a moment."""
    with anyio.fail_after(10.0):
        while frame not in backend.tf_frames():  # noqa: ASYNC110 - filled by the ROS executor thread
            await anyio.sleep(0.02)


async def test_a_transform_from_tf_static_is_looked_up_and_composed(cell: Cell) -> None:
    async with opened() as backend:
        camera = cell.config.camera_frame
        await wait_for_frame(backend, camera)
        reading = await backend.lookup_transform(cell.robot.base_frame, camera)
        inverse = await backend.lookup_transform(camera, cell.robot.base_frame)
    np.testing.assert_allclose(reading.translation, [1.2, 0.0, 0.8], atol=1e-12)
    assert abs(np.dot(reading.rotation_xyzw, [0.5, -0.5, 0.5, -0.5])) == pytest.approx(1.0)
    np.testing.assert_allclose(np.linalg.norm(inverse.translation), np.linalg.norm([1.2, 0.0, 0.8]), atol=1e-12)


async def test_the_lookup_transform_tool_reads_tf_for_frames_the_robot_model_lacks(cell: Cell) -> None:
    async with opened() as backend:
        await wait_for_frame(backend, cell.config.camera_frame)
        readings = Readings(POLICY, ROBOT, backend, time.monotonic)
        from_tf = await readings.lookup_transform(ROBOT.base_frame, cell.config.camera_frame)
        from_model = await readings.lookup_transform(ROBOT.base_frame, ROBOT.tcp_frame)
    position = from_tf.pose.position
    assert (position.x, position.y, position.z) == pytest.approx((1.2, 0.0, 0.8))
    expected_tcp = ROBOT.tcp_pose(cell.positions()).position
    assert (from_model.pose.position.x, from_model.pose.position.z) == pytest.approx((expected_tcp[0], expected_tcp[2]))


async def test_an_unknown_frame_is_refused_listing_the_known_ones(cell: Cell) -> None:
    async with opened() as backend:
        with pytest.raises(BackendError, match=r"unknown frame 'moon'; frames on /tf and /tf_static: "):
            await backend.lookup_transform("moon", cell.robot.base_frame)


# ---------------------------------------------------------------------------- the parts' deadlines
def test_the_camera_and_gripper_parts_carry_the_deadlines_their_config_sets() -> None:
    gripper = {**example_document()["gripper"], "max_width_m": 0.06}
    cell = build_backend(example_config(cameras=CAMERAS, gripper=gripper)).cell
    assert cell.cameras is not None and cell.cameras.timeout_s == pytest.approx(2.0 + 0.5)  # slowest wait + margin
    assert cell.gripper is not None and cell.gripper.travel_m == 0.06  # a move may cross the full opening


# ---------------------------------------------------------------------------- absent parts
async def test_without_optional_sections_no_optional_capability_is_declared(cell: Cell) -> None:
    joint_states = {**example_document()["joint_states"], "efforts": False}
    config = example_config(wrench=None, gripper=None, controller_manager=None, error_recovery=None, cameras={},
                            tf={"enabled": False}, joint_states=joint_states)
    async with opened(config) as backend:
        assert backend.capabilities == Capabilities(graph=True)
        assert await backend.read_wrench() is None and await backend.gripper_state() is None
        for call in (backend.gripper_home(), backend.list_controllers(), backend.error_recovery(),
                     backend.lookup_transform("fr3_link0", "fr3_link0")):
            with pytest.raises(BackendError, match="has no"):
                await call
