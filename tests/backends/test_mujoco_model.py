"""The MuJoCo model of the cell: built from the same URDF as the Pinocchio model, and it must not
drift from it — the same kinematics, the envelope's bodies as collision geometry (the fitted
capsules of the bundled FR3, or the URDF's primitives without them), self-contacts only where the
envelope looks, and the parts the backend will drive (actuators, gripper, flange sensor, cameras,
table)."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

mujoco = pytest.importorskip("mujoco")

from armwarden.backends.mujoco.gripper_model import capsule_contains  # noqa: E402 - after the importorskip above
from armwarden.backends.mujoco.model import MujocoModel, build_model  # noqa: E402
from armwarden.backends.mujoco.names import (  # noqa: E402
    ENVELOPE_PREFIX,
    FLANGE_SITE,
    FORCE_SENSOR,
    GRIPPER_ACTUATOR,
    TABLE_GEOM,
    TORQUE_SENSOR,
)
from armwarden.backends.mujoco.scene import SceneObject, scene_for_policy  # noqa: E402
from armwarden.policy import load_policy  # noqa: E402
from armwarden.policy.loading import bundled_policy  # noqa: E402
from armwarden.robot import build_robot  # noqa: E402
from armwarden.robot.fitted_file import ExcludedPair  # noqa: E402
from armwarden.robot.ik import IkSolver  # noqa: E402
from armwarden.robot.model import RobotModel, resolve_description  # noqa: E402
from armwarden.safety.envelope import Envelope  # noqa: E402
from armwarden.safety.limits import EnvelopeLimits  # noqa: E402

ARM = tuple(f"fr3_joint{i}" for i in range(1, 8))
FINGERS = ("fr3_finger_joint1", "fr3_finger_joint2")
CONFIGURATIONS = 200


@pytest.fixture(scope="module")
def policy():
    return load_policy(bundled_policy("fr3"))


@pytest.fixture(scope="module")
def robot(policy) -> RobotModel:
    return build_robot(policy)


@pytest.fixture(scope="module")
def cell(policy, robot) -> MujocoModel:
    return build_model(resolve_description(policy.robot.description), robot, scene_for_policy(policy))


@pytest.fixture(scope="module")
def urdf_robot(policy) -> RobotModel:
    """The bundled FR3 with the URDF's own collision primitives instead of the fitted capsules."""
    robot = RobotModel.from_description(policy.robot.description, policy.robot.joint_names, policy.robot.base_frame,
                                        policy.robot.tcp_frame, collision_geometry="urdf")
    robot.set_position_limits(np.array(policy.robot.lower_limits), np.array(policy.robot.upper_limits))
    return robot


@pytest.fixture(scope="module")
def urdf_cell(policy, urdf_robot) -> MujocoModel:
    return build_model(resolve_description(policy.robot.description), urdf_robot, scene_for_policy(policy))


@pytest.fixture(scope="module")
def pinocchio_with_fingers() -> RobotModel:
    """The same URDF in Pinocchio with the finger joints free too, so every body can be compared."""
    return RobotModel(resolve_description("builtin:fr3"), ARM + FINGERS, "fr3_link0", "fr3_hand_tcp")


@pytest.fixture(scope="module")
def random_configurations(pinocchio_with_fingers) -> np.ndarray:
    rng = np.random.default_rng(20261123)
    return rng.uniform(pinocchio_with_fingers.lower, pinocchio_with_fingers.upper,
                       size=(CONFIGURATIONS, pinocchio_with_fingers.nq))


def mujoco_poses(cell: MujocoModel, q: np.ndarray):
    data = mujoco.MjData(cell.model)
    data.qpos[cell.arm_qpos] = q[: len(ARM)]
    data.qpos[cell.finger_qpos] = q[len(ARM):]
    mujoco.mj_kinematics(cell.model, data)
    return data


def robot_bodies(cell: MujocoModel) -> list[str]:
    return [cell.model.body(i).name for i in range(1, cell.model.nbody)]


def test_every_urdf_link_is_a_mujoco_body(cell, pinocchio_with_fingers):
    assert sorted(robot_bodies(cell)) == sorted(pinocchio_with_fingers.link_names())


def test_pinocchio_and_mujoco_agree_on_every_body_origin(cell, pinocchio_with_fingers, random_configurations):
    worst = 0.0
    for q in random_configurations:
        data = mujoco_poses(cell, q)
        for body in robot_bodies(cell):
            expected = pinocchio_with_fingers.frame_pose(q, body).position
            worst = max(worst, float(np.linalg.norm(data.body(body).xpos - expected)))
    assert worst < 1e-6


def test_pinocchio_and_mujoco_agree_on_every_body_orientation(cell, pinocchio_with_fingers, random_configurations):
    worst = 0.0
    for q in random_configurations:
        data = mujoco_poses(cell, q)
        for body in robot_bodies(cell):
            expected = pinocchio_with_fingers.frame_pose(q, body).rotation
            worst = max(worst, float(np.abs(data.body(body).xmat.reshape(3, 3) - expected).max()))
    assert worst < 1e-6


def capsule_ends_in_body_frame(model, geom_id: int) -> tuple[np.ndarray, np.ndarray]:
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[geom_id])
    axis = rotation.reshape(3, 3)[:, 2] * model.geom_size[geom_id][1]
    center = model.geom_pos[geom_id]
    return center - axis, center + axis


def test_without_fitted_geometry_every_envelope_capsule_is_a_geom_with_its_radius_and_end_points(urdf_cell, urdf_robot):
    model, robot = urdf_cell.model, urdf_robot
    for capsule in robot.capsules:
        geom = model.geom(ENVELOPE_PREFIX + capsule.name)
        assert model.body(int(geom.bodyid[0])).name == capsule.link
        assert geom.type[0] == mujoco.mjtGeom.mjGEOM_CAPSULE
        assert abs(geom.size[0] - capsule.radius_m) < 1e-9
        # the capsule's ends are in its joint's frame; the geom's in its link's body frame
        link_in_joint = robot.model.frames[robot.frame_id(capsule.link)].placement
        a, b = capsule_ends_in_body_frame(model, geom.id)
        ends = sorted([link_in_joint.act(a), link_in_joint.act(b)], key=tuple)
        expected = sorted([np.array(capsule.p0_m), np.array(capsule.p1_m)], key=tuple)
        assert np.abs(np.array(ends) - np.array(expected)).max() < 1e-9, capsule.name


@pytest.mark.parametrize("which", ["fitted", "urdf"])
def test_the_robot_collides_only_through_envelope_capsules_and_finger_pads(which, cell, urdf_cell):
    model = (cell if which == "fitted" else urdf_cell).model
    robot_body_ids = set(range(2, model.nbody))  # 0 is the world, 1 the base welded to it
    colliding = [model.geom(i).name for i in range(model.ngeom)
                 if model.geom_bodyid[i] in robot_body_ids and (model.geom_contype[i] or model.geom_conaffinity[i])]
    assert colliding
    assert all(name.startswith((ENVELOPE_PREFIX, "pad/")) for name in colliding)


def test_without_fitted_geometry_only_the_finger_sweep_capsule_is_left_out_of_contacts(urdf_cell):
    model = urdf_cell.model
    silent = [model.geom(i).name for i in range(model.ngeom)
              if model.geom(i).name.startswith(ENVELOPE_PREFIX) and not model.geom_contype[i]]
    assert silent == [ENVELOPE_PREFIX + "fr3_hand_1"]  # the fingers capsule of the bundled URDF


def test_without_fitted_geometry_the_finger_pads_stay_inside_the_finger_sweep_capsule_at_every_opening(urdf_cell):
    cell = urdf_cell
    model = cell.model
    sweep = model.geom(ENVELOPE_PREFIX + "fr3_hand_1")
    for width in np.linspace(0.0, 0.08, 9):
        data = mujoco.MjData(model)
        data.qpos[cell.finger_qpos] = width / 2.0
        mujoco.mj_kinematics(model, data)
        center, rotation = data.geom(sweep.id).xpos, data.geom(sweep.id).xmat.reshape(3, 3)
        a, b = center - rotation[:, 2] * sweep.size[1], center + rotation[:, 2] * sweep.size[1]
        for finger in ("fr3_leftfinger", "fr3_rightfinger"):
            pad = data.geom(f"pad/{finger}")
            half = model.geom(f"pad/{finger}").size
            pad_rotation = pad.xmat.reshape(3, 3)
            for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3):
                corner = pad.xpos + pad_rotation @ (signs * half)
                assert capsule_contains(a, b, float(sweep.size[0]), corner), (width, finger, signs)


def test_every_fitted_body_is_a_capsule_geom_on_its_link_in_the_link_frame(cell, robot):
    model = cell.model
    assert robot.fitted is not None
    for link, fit in robot.fitted.links.items():
        for body in fit.bodies:
            geom = model.geom(ENVELOPE_PREFIX + body.name)
            assert model.body(int(geom.bodyid[0])).name == link
            assert geom.type[0] == mujoco.mjtGeom.mjGEOM_CAPSULE
            assert abs(geom.size[0] - body.radius_m) < 1e-9
            ends = sorted(capsule_ends_in_body_frame(model, geom.id), key=tuple)
            expected = sorted([np.array(body.p0_m), np.array(body.p1_m)], key=tuple)
            assert np.abs(np.array(ends) - np.array(expected)).max() < 1e-9, body.name


def is_collidable(model, geom_id: int) -> bool:
    return bool(model.geom_contype[geom_id] or model.geom_conaffinity[geom_id])


def robot_contact_geoms(model) -> list[int]:
    """Geoms on the robot's bodies (the base welded to the world included) that take part in contacts."""
    return [i for i in range(model.ngeom) if model.geom_bodyid[i] != 0 and is_collidable(model, i)]


def geom_points(model, data, geom_id: int) -> tuple[list[np.ndarray], float]:
    """Points and a radius whose swept ball is the geom (capsule: ends; sphere: centre; box: corners)."""
    centre, rotation, size = data.geom_xpos[geom_id], data.geom_xmat[geom_id].reshape(3, 3), model.geom_size[geom_id]
    kind = model.geom_type[geom_id]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return [centre - rotation[:, 2] * size[1], centre + rotation[:, 2] * size[1]], float(size[0])
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return [centre], float(size[0])
    assert kind == mujoco.mjtGeom.mjGEOM_BOX, model.geom(geom_id).name
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3) * size
    return [centre + rotation @ corner for corner in corners], 0.0


def segment_distance(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    segment = b - a
    t = float(np.clip((point - a) @ segment / (segment @ segment), 0.0, 1.0)) if segment @ segment > 0 else 0.0
    return float(np.linalg.norm(point - (a + t * segment)))


def test_every_contact_geom_of_the_robot_lies_inside_an_envelope_body_of_its_link(cell, robot, random_configurations):
    """Capsules, spheres and boxes are convex: ends (corners) inside one envelope capsule, grown
    by nothing but shrunk by the geom's own radius, put all of the geom inside it."""
    model = cell.model
    links = np.array([capsule.link for capsule in robot.capsules])
    geoms = robot_contact_geoms(model)
    for q in random_configurations:  # the fingers anywhere in their travel: the envelope sweeps them
        data = mujoco_poses(cell, q)
        p0, p1 = robot.body_points(robot.joint_frames(q[None, :len(ARM)]))
        for geom in geoms:
            points, radius = geom_points(model, data, geom)
            own = np.flatnonzero(links == model.body(int(model.geom_bodyid[geom])).name)
            inside = [all(segment_distance(point, p0[0, k], p1[0, k]) <= robot.capsule_radii[k] - radius + 1e-9
                          for point in points) for k in own]
            assert any(inside), (model.geom(geom).name, q)


def robot_self_contact_pairs(model) -> set[frozenset[str]]:
    """Envelope body pairs (by name) whose contact geoms MuJoCo brings into contact, asked of MuJoCo
    itself: with every contact margin overridden to 10 m, each geom pair that passes its filters
    (contype/conaffinity, same or parent body, excludes; explicit pairs) is in contact anywhere."""
    probe = copy.deepcopy(model)
    probe.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_OVERRIDE
    probe.opt.o_margin = 10.0
    data = mujoco.MjData(probe)
    mujoco.mj_forward(probe, data)
    assert data.warning[mujoco.mjtWarning.mjWARN_CONTACTFULL].number == 0
    robot_geoms = set(robot_contact_geoms(probe))
    # geoms are named envelope/<body> or pad/<body>: a pad stands in for the body it lies in
    return {frozenset(probe.geom(g).name.split("/", 1)[1] for g in (contact.geom1, contact.geom2))
            for contact in data.contact[:data.ncon]
            if contact.geom1 in robot_geoms and contact.geom2 in robot_geoms}


def envelope_pairs(robot: RobotModel) -> set[frozenset[str]]:
    return {frozenset((robot.capsules[a].name, robot.capsules[b].name)) for a, b in robot.self_collision_pairs}


def test_mujoco_makes_contacts_between_every_body_pair_the_envelope_checks(cell, robot):
    assert envelope_pairs(robot) <= robot_self_contact_pairs(cell.model)


def test_every_self_contact_mujoco_can_make_is_one_the_envelope_checks_or_one_proved_never_to_happen(cell, robot):
    apart = {frozenset(pair.bodies) for pair in robot.fitted.excluded_pairs if pair.reason == "apart"}
    unchecked = robot_self_contact_pairs(cell.model) - envelope_pairs(robot)
    assert unchecked <= apart, sorted(sorted(pair) for pair in unchecked - apart)[:10]


def test_a_link_pair_with_bodies_in_contact_by_construction_is_excluded_and_keeps_the_pairs_the_envelope_checks(policy):
    """MuJoCo excludes whole body pairs: where one link pair holds both a pair in contact by
    construction and pairs the envelope checks, the checked ones stay in contact as explicit pairs."""
    fitted = build_robot(policy).fitted
    assert fitted is not None
    bodies = ("fr3_link5/0", "fr3_link7/0")  # pretend these always overlap
    touching = frozenset(bodies)
    fitted = dataclasses.replace(
        fitted,
        included_pairs=tuple(pair for pair in fitted.included_pairs if frozenset(pair) != touching),
        excluded_pairs=(*fitted.excluded_pairs, ExcludedPair(bodies, "overlapping", "a test")),
    )
    robot_cfg = policy.robot
    robot = RobotModel(resolve_description(robot_cfg.description), robot_cfg.joint_names, robot_cfg.base_frame,
                       robot_cfg.tcp_frame, fitted=fitted)
    checked = envelope_pairs(robot)
    assert touching not in checked
    assert any({name.split("/")[0] for name in pair} == {"fr3_link5", "fr3_link7"} for pair in checked)
    contacts = robot_self_contact_pairs(build_model(resolve_description(robot_cfg.description), robot,
                                                    scene_for_policy(policy)).model)
    assert touching not in contacts
    assert checked <= contacts


def test_a_top_down_grasp_with_joint_6_near_3_rad_makes_no_self_contact(cell, robot, policy):
    """The wrist folds (joint 6 above 2.8 rad) for every top-down grasp in front of the FR3; the
    envelope allows it, so MuJoCo must not make link5 touch link7 there."""
    home = np.array(policy.robot.home_joint_positions)
    hand_down = np.diag([1.0, -1.0, -1.0])
    solution = IkSolver(robot).solve(np.array([0.45, 0.0, 0.05]), hand_down, [home])
    assert solution.success and solution.q[5] > 2.8
    assert Envelope(robot, EnvelopeLimits.from_policy(policy)).check_path(solution.q) == ()
    model = cell.model
    robot_geoms = set(robot_contact_geoms(model))
    for width in (0.0, 0.04, 0.08):
        data = mujoco.MjData(model)
        cell.set_arm_positions(data, solution.q)
        data.qpos[cell.finger_qpos] = width / 2.0
        mujoco.mj_forward(model, data)
        self_contacts = [(model.geom(c.geom1).name, model.geom(c.geom2).name) for c in data.contact[:data.ncon]
                         if c.geom1 in robot_geoms and c.geom2 in robot_geoms]
        assert self_contacts == [], width


def test_fitted_finger_capsules_that_reach_past_the_closing_plane_leave_contacts_to_pads_on_it(cell, robot):
    """The fingers meet at the closing plane (the finger frames' origin, normal to their travel)
    when closed; a capsule's rounding past it would grasp an object before the finger's real
    face does. Such a capsule stays in the model without contacts, and a box inside it with one
    face on the plane takes its contacts."""
    model = cell.model
    silent = sorted(model.geom(i).name for i in range(model.ngeom)
                    if model.geom(i).name.startswith(ENVELOPE_PREFIX) and not is_collidable(model, i))
    assert silent == [ENVELOPE_PREFIX + f"{finger}/{k}" for finger in ("fr3_leftfinger", "fr3_rightfinger")
                      for k in (5, 6)]
    for name in silent:
        body = name[len(ENVELOPE_PREFIX):]
        finger = body.split("/")[0]
        axis = model.jnt_axis[model.body(finger).jntadr[0]]
        pad = model.geom("pad/" + body)
        capsule = model.geom(name)
        assert model.body(int(pad.bodyid[0])).name == finger and is_collidable(model, pad.id)
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, pad.quat)
        corners = [pad.pos + rotation.reshape(3, 3) @ (signs * pad.size)
                   for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)]
        assert min(float(axis @ corner) for corner in corners) == pytest.approx(0.0, abs=1e-9)
        a, b = capsule_ends_in_body_frame(model, capsule.id)
        assert all(capsule_contains(a, b, float(capsule.size[0]), corner) for corner in corners)


def test_the_arm_has_one_position_actuator_per_joint_limited_by_the_urdf_effort(cell):
    model = cell.model
    assert [model.actuator(int(i)).name for i in cell.arm_actuators] == list(ARM)
    efforts = [87.0] * 4 + [12.0] * 3
    for index, name in enumerate(ARM):
        actuator = model.actuator(name)
        assert model.joint(int(actuator.trnid[0])).name == name
        assert actuator.gainprm[0] == pytest.approx(cell.gains.kp[index])
        assert actuator.biasprm[2] == pytest.approx(-cell.gains.kv[index])
        assert tuple(model.jnt_actfrcrange[model.joint(name).id]) == (-efforts[index], efforts[index])


def test_the_fingers_are_actuated_by_one_width_actuator_capped_at_the_policy_grasp_force(cell, policy):
    model = cell.model
    gripper = model.actuator(GRIPPER_ACTUATOR)
    assert cell.gripper_actuator == gripper.id
    assert cell.finger_joints == FINGERS
    assert all(model.joint(name).type[0] == mujoco.mjtJoint.mjJNT_SLIDE for name in FINGERS)
    limit = policy.gripper.max_grasp_force_n
    assert tuple(gripper.forcerange) == (-limit, limit)
    assert tuple(gripper.ctrlrange) == pytest.approx((0.0, 0.08))


def test_the_flange_carries_a_site_with_force_and_torque_sensors(cell):
    model = cell.model
    site = model.site(FLANGE_SITE)
    assert model.body(int(site.bodyid[0])).name == "fr3_link8" == cell.flange_body
    for sensor in (FORCE_SENSOR, TORQUE_SENSOR):
        assert model.sensor(sensor).objid[0] == site.id


def test_the_scene_and_wrist_cameras_exist(cell):
    model = cell.model
    assert cell.cameras == ("scene", "wrist")
    assert model.body(int(model.camera("scene").bodyid[0])).name == "world"
    assert model.body(int(model.camera("wrist").bodyid[0])).name == "fr3_hand"
    assert model.nlight >= 1


def test_the_table_top_is_the_workspace_floor(cell, policy):
    data = mujoco.MjData(cell.model)
    mujoco.mj_kinematics(cell.model, data)
    top = data.geom(TABLE_GEOM).xpos[2] + cell.model.geom(TABLE_GEOM).size[2]
    assert top == pytest.approx(policy.workspace.box.min[2], abs=1e-12)


def test_the_arm_holds_the_home_pose_against_gravity_without_touching_anything(cell, policy):
    model = cell.model
    data = mujoco.MjData(model)
    home = np.array(policy.robot.home_joint_positions)
    cell.set_arm_positions(data, home)
    for _ in range(1000):  # one simulated second
        mujoco.mj_step(model, data)
    assert data.ncon == 0
    assert np.abs(data.qpos[cell.arm_qpos] - home).max() < 1e-6


def test_the_flange_sensor_at_rest_reads_the_weight_of_the_hand(cell, policy):
    model = cell.model
    data = mujoco.MjData(model)
    cell.set_arm_positions(data, np.array(policy.robot.home_joint_positions))
    for _ in range(200):
        mujoco.mj_step(model, data)
    flange = model.body(cell.flange_body).id
    weight_n = model.body_subtreemass[flange] * -model.opt.gravity[2]
    force = data.sensordata[cell.force_sensor_adr:cell.force_sensor_adr + 3]
    assert np.linalg.norm(force) == pytest.approx(weight_n, rel=1e-3)


def quintic(start: np.ndarray, goal: np.ndarray, duration_s: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    s = min(t / duration_s, 1.0)
    shape = 10 * s**3 - 15 * s**4 + 6 * s**5
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / duration_s
    return start + (goal - start) * shape, (goal - start) * rate


def test_the_servo_with_velocity_feed_forward_tracks_a_smooth_move_and_ends_at_its_goal(cell, policy):
    model = cell.model
    data = mujoco.MjData(model)
    home = np.array(policy.robot.home_joint_positions)
    goal = home + np.array([0.8, 0.3, -0.4, 0.5, 0.6, -0.4, 1.0])
    cell.set_arm_positions(data, home)
    duration_s, worst = 2.0, 0.0
    for step in range(int(2.5 / model.opt.timestep)):  # the move, then half a second of holding
        q, qd = quintic(home, goal, duration_s, (step + 1) * model.opt.timestep)
        data.ctrl[cell.arm_actuators] = cell.arm_ctrl(q, qd)
        mujoco.mj_step(model, data)
        worst = max(worst, float(np.abs(data.qpos[cell.arm_qpos] - q).max()))
    assert worst < 2e-3  # rad, during the move
    assert np.abs(data.qpos[cell.arm_qpos] - goal).max() < 1e-6


def test_a_box_squeezed_between_the_finger_pads_is_held_by_friction_alone(policy, robot):
    home = np.array(policy.robot.home_joint_positions)
    box = SceneObject("box", "box", tuple(robot.tcp_pose(home).position), (0.04, 0.04, 0.04), mass_kg=0.2)
    cell = build_model(resolve_description(policy.robot.description), robot, scene_for_policy(policy, objects=(box,)))
    model = cell.model
    assert model.neq == 1  # only the finger coupling: nothing welds the box to the hand
    data = mujoco.MjData(model)
    cell.set_arm_positions(data, home)
    data.qpos[cell.finger_qpos] = 0.04  # open, the box floating between the pads
    data.ctrl[cell.gripper_actuator] = 0.0  # close on it
    for _ in range(500):
        mujoco.mj_step(model, data)
    gripped_z = data.body("box").xpos[2]
    for _ in range(1000):
        mujoco.mj_step(model, data)
    assert abs(data.body("box").xpos[2] - gripped_z) < 1e-4  # [m] it does not slip out
    # the fingers press on the box's sides with their real inner faces (the plane they meet in when
    # closed): the width is the box's less how far the soft contacts sink in on each side
    box_geom = model.geom("box").id
    depth = max(-c.dist for c in data.contact[:data.ncon] if box_geom in (c.geom1, c.geom2))
    assert 0.0 < depth < 0.003
    assert data.qpos[cell.finger_qpos].sum() + 2.0 * depth == pytest.approx(0.04, abs=5e-4)
