"""The fake FR3 cell behaves like the ROS endpoints of a real cell, seen from a plain rclpy client."""

from __future__ import annotations

import time

import numpy as np
import pytest
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory
from controller_manager_msgs.srv import ListControllers, SwitchController
from sensor_msgs.msg import Image

from tests_ros.cell import Cell, CellConfig, GoalMode
from tests_ros.client import RosClient, eventually

HOME = [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]
QUIET_S = 0.3  # long enough for ~30 joint-state periods: "nothing changes" is observable


def moved_joint1(delta: float) -> list[float]:
    target = list(HOME)
    target[0] += delta
    return target


def test_joint_states_name_the_policy_joints_and_start_at_home(client: RosClient) -> None:
    msg = client.wait_latest("joint_states")

    assert list(msg.name) == [f"fr3_joint{i}" for i in range(1, 8)]
    assert np.allclose(msg.position, HOME)


def test_a_trajectory_goal_streams_feedback_moves_the_joints_and_succeeds(cell: Cell, client: RosClient) -> None:
    names = client.wait_latest("joint_states").name
    handle = client.send_goal(client.trajectory_goal(names, [moved_joint1(0.1), moved_joint1(0.3)], [0.3, 0.6]))

    outcome = client.result(handle)

    assert handle.accepted
    assert outcome.status == GoalStatus.STATUS_SUCCEEDED
    assert outcome.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    assert len(client.feedback) > 5
    assert eventually(lambda: abs(client.positions()[0] - 0.3) < 1e-6, what="joint states at the goal")
    assert cell.counters().goals_accepted == 1


def test_goal_joints_in_another_order_are_mapped_by_name(cell: Cell, client: RosClient) -> None:
    names = list(reversed(client.wait_latest("joint_states").name))
    target = list(reversed(moved_joint1(0.2)))

    outcome = client.result(client.send_goal(client.trajectory_goal(names, [target], [0.3])))

    assert outcome.status == GoalStatus.STATUS_SUCCEEDED
    assert cell.positions()[0] == pytest.approx(0.2)


def test_cancel_stops_the_arm_where_it_is(cell: Cell, client: RosClient) -> None:
    names = client.wait_latest("joint_states").name
    handle = client.send_goal(client.trajectory_goal(names, [moved_joint1(1.0)], [5.0]))
    eventually(lambda: cell.positions()[0] > 0.05, what="the arm moving")

    client.cancel(handle)
    outcome = client.result(handle)
    held = cell.positions()
    time.sleep(QUIET_S)

    assert outcome.status == GoalStatus.STATUS_CANCELED
    assert 0.05 < held[0] < 1.0
    assert np.array_equal(cell.positions(), held)
    assert cell.counters().cancels_received == 1


@pytest.mark.parametrize("cell_config", [CellConfig(goal_mode=GoalMode.REJECT)])
def test_reject_mode_refuses_goals_and_counts_them_received_not_accepted(cell: Cell, client: RosClient) -> None:
    names = client.wait_latest("joint_states").name

    handle = client.send_goal(client.trajectory_goal(names, [moved_joint1(0.3)], [0.5]))

    assert not handle.accepted
    assert cell.counters().goals_received == 1
    assert cell.counters().goals_accepted == 0
    assert np.allclose(cell.positions(), HOME)


def test_a_goal_for_other_joints_is_rejected(cell: Cell, client: RosClient) -> None:
    handle = client.send_goal(client.trajectory_goal(["elbow", "wrist"], [[0.1, 0.2]], [0.5]))

    assert not handle.accepted
    assert cell.counters().goals_accepted == 0


def test_an_empty_trajectory_is_rejected_like_jazzys_controller(cell: Cell, client: RosClient) -> None:
    names = client.wait_latest("joint_states").name

    handle = client.send_goal(client.trajectory_goal(names, [], []))

    assert not handle.accepted


@pytest.mark.parametrize("cell_config", [CellConfig(goal_mode=GoalMode.ABORT, abort_after_s=0.2)])
def test_abort_mode_aborts_with_a_path_tolerance_error(cell: Cell, client: RosClient) -> None:
    names = client.wait_latest("joint_states").name

    outcome = client.result(client.send_goal(client.trajectory_goal(names, [moved_joint1(1.0)], [5.0])))

    assert outcome.status == GoalStatus.STATUS_ABORTED
    assert outcome.result.error_code == FollowJointTrajectory.Result.PATH_TOLERANCE_VIOLATED
    assert "path tolerance" in outcome.result.error_string
    assert cell.counters().goals_aborted == 1


@pytest.mark.parametrize("cell_config", [CellConfig(goal_mode=GoalMode.DIE, die_after_s=0.2)])
def test_a_cell_that_dies_mid_motion_goes_silent(cell: Cell, client: RosClient) -> None:
    names = client.wait_latest("joint_states").name
    handle = client.send_goal(client.trajectory_goal(names, [moved_joint1(1.0)], [5.0]))
    eventually(lambda: cell.dead, what="the cell dying")
    last = cell.last_joint_state_stamp()
    eventually(lambda: client.latest("joint_states").header.stamp == last,
               what="the last joint state sent before the death")  # it may still be in flight
    count = client.joint_state_count

    time.sleep(QUIET_S)

    assert handle.accepted
    assert client.joint_state_count == count
    assert not handle.get_result_async().done()


def test_paused_joint_states_stop_arriving(cell: Cell, client: RosClient) -> None:
    client.wait_latest("joint_states")
    cell.pause_joint_states()
    last = cell.last_joint_state_stamp()
    eventually(lambda: client.latest("joint_states").header.stamp == last,
               what="the last joint state sent before the pause")  # it may still be in flight
    count = client.joint_state_count

    time.sleep(QUIET_S)

    assert client.joint_state_count == count


def test_a_frozen_wrench_keeps_its_stamp(cell: Cell, client: RosClient) -> None:
    client.wait_latest("wrench")
    frozen = cell.freeze_wrench_stamp()
    eventually(lambda: client.latest("wrench").header.stamp == frozen, what="a wrench with the frozen stamp")

    time.sleep(QUIET_S)

    assert client.latest("wrench").header.stamp == frozen


def test_without_a_table_the_wrench_is_zero(client: RosClient) -> None:
    wrench = client.wait_latest("wrench")

    assert wrench.wrench.force.z == 0.0
    assert wrench.header.frame_id == "fr3_link0"


# The home pose puts the TCP at z = 0.4869 m: a table at 0.55 m is 6.3 cm above it.
@pytest.mark.parametrize("cell_config", [CellConfig(table_height_m=0.55, table_stiffness_n_per_m=1000.0)])
def test_a_tcp_below_the_virtual_table_feels_an_upward_force(client: RosClient) -> None:
    force = eventually(lambda: (w := client.latest("wrench")) is not None and w.wrench.force.z, what="a contact force")

    assert force == pytest.approx(1000.0 * (0.55 - 0.4869), abs=0.5)


@pytest.mark.parametrize("cell_config", [CellConfig(table_height_m=0.40)])
def test_a_tcp_above_the_virtual_table_feels_nothing(client: RosClient) -> None:
    assert client.wait_latest("wrench").wrench.force.z == 0.0


def test_the_camera_image_is_rgb8_and_changes_when_the_arm_moves(cell: Cell, client: RosClient) -> None:
    before = client.wait_latest("image")
    names = client.wait_latest("joint_states").name
    client.result(client.send_goal(client.trajectory_goal(names, [moved_joint1(0.5)], [0.3])))

    def changed_image() -> Image | None:
        image = client.latest("image")
        return image if image is not None and image.data != before.data else None

    after = eventually(changed_image, what="a new image")

    assert (before.encoding, before.width, before.height, before.step) == ("rgb8", 64, 48, 64 * 3)
    assert len(after.data) == 64 * 48 * 3


def test_a_static_transform_places_the_camera_in_the_base_frame(client: RosClient) -> None:
    (transform,) = client.wait_latest("tf_static").transforms

    assert transform.header.frame_id == "fr3_link0"
    assert transform.child_frame_id == "scene_camera_color_optical_frame"


def test_the_gripper_moves_to_the_commanded_width(cell: Cell, client: RosClient) -> None:
    handle, outcome = client.grip(0.03)

    assert handle.accepted
    assert outcome.status == GoalStatus.STATUS_SUCCEEDED
    assert outcome.result.reached_goal
    assert cell.gripper_width() == pytest.approx(0.03)


def test_list_controllers_reports_the_arm_controller_active(client: RosClient) -> None:
    response = client.call(client.list_client, ListControllers.Request())

    assert {c.name: c.state for c in response.controller}["fr3_arm_controller"] == "active"


def test_switch_controller_activates_and_deactivates(cell: Cell, client: RosClient) -> None:
    request = SwitchController.Request(
        activate_controllers=["joint_impedance_controller"],
        deactivate_controllers=["fr3_arm_controller"],
        strictness=SwitchController.Request.STRICT,
    )

    response = client.call(client.switch_client, request)

    assert response.ok
    assert cell.controller_states()["joint_impedance_controller"] == "active"
    assert cell.controller_states()["fr3_arm_controller"] == "inactive"


def test_switching_an_unknown_controller_fails_and_changes_nothing(cell: Cell, client: RosClient) -> None:
    before = cell.controller_states()

    response = client.call(client.switch_client, SwitchController.Request(activate_controllers=["nope"], strictness=2))

    assert not response.ok
    assert "nope" in response.message
    assert cell.controller_states() == before
