"""The cell around the robot in the MuJoCo model: the table at the policy's workspace floor, the
floor, lights, the cameras and loose objects. What the cell is (`SceneSpec`) is plain data from
the policy and the backend config; `add_cell` puts it into the spec in the URDF root frame (MuJoCo's
world), given where the policy's base frame sits in it.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.mujoco.camera_mounts import CameraSpec, look_at_quat, profile_cameras
from armwarden.backends.mujoco.names import FLOOR_GEOM, TABLE_GEOM
from armwarden.core.errors import RobotModelError

if TYPE_CHECKING:
    from armwarden.policy import Policy


@dataclass(frozen=True)
class SceneObject:
    """A rigid object in the cell: a box or an upright cylinder, loose (a free body) or `fixed`
    (welded to the world: an obstacle nothing moves, e.g. one the policy does not know of).

    `position_m` is its centre in the base frame, `yaw_rad` its rotation about the vertical;
    `size_m` the box's full (x, y, z) extents or the cylinder's (diameter, —, height)."""

    name: str
    shape: str  # "box" | "cylinder"
    position_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    mass_kg: float
    yaw_rad: float = 0.0
    friction: float = 1.0
    rgba: tuple[float, float, float, float] = (0.85, 0.2, 0.15, 1.0)
    fixed: bool = False


@dataclass(frozen=True)
class SceneSpec:
    """The cell around the robot; lengths [m] in the policy's base frame."""

    #: height of the table top = the policy's workspace floor (`workspace.box.min[2]`)
    table_top_z_m: float
    #: table footprint (x_min, y_min, x_max, y_max), e.g. the workspace box's
    table_xy_m: tuple[float, float, float, float]
    #: the floor lies this far below the table top
    table_height_m: float = 0.75
    table_thickness_m: float = 0.04
    table_friction: float = 0.8
    #: the robot profile's mounts for a built-in robot (`scene_for_policy`)
    cameras: tuple[CameraSpec, ...] = ()
    objects: tuple[SceneObject, ...] = ()
    #: physics step [s]
    timestep_s: float = 0.001
    #: largest grasp force the finger actuator can apply [N] (the policy's `gripper.max_grasp_force_n`)
    gripper_force_limit_n: float = 70.0


def scene_for_policy(policy: Policy, **overrides: Any) -> SceneSpec:
    """The cell the policy describes: the table top is the workspace floor and covers the workspace
    box's footprint; the finger force limit is the policy's grasp force cap; the cameras are the
    robot profile's, or one in front of the workspace for an arm without a profile
    (`profile_cameras`). `overrides` replace any other `SceneSpec` field."""
    box = policy.workspace.box
    cameras = overrides.get("cameras")
    scene = SceneSpec(table_top_z_m=float(box.min[2]),
                      table_xy_m=(float(box.min[0]), float(box.min[1]), float(box.max[0]), float(box.max[1])),
                      cameras=profile_cameras(policy.robot.description, box.min, box.max) if cameras is None else cameras)
    if policy.gripper is not None:
        scene = replace(scene, gripper_force_limit_n=float(policy.gripper.max_grasp_force_n))
    return replace(scene, **overrides)

def add_cell(spec: mujoco.MjSpec, scene: SceneSpec, world_from_base: pin.SE3) -> None:
    """Table, floor, lights, cameras and objects of `scene` into `spec` (base-frame positions
    placed through `world_from_base`)."""
    _Cell(spec, scene, world_from_base).add()


class _Cell:
    """Adds the cell's parts to the spec (`add_cell`), base-frame positions moved into the world."""

    def __init__(self, spec: mujoco.MjSpec, scene: SceneSpec, world_from_base: pin.SE3) -> None:
        self.spec = spec
        self.scene = scene
        self.world_from_base = world_from_base

    def _to_world(self, point: Sequence[float] | np.ndarray) -> np.ndarray:
        return self.world_from_base.act(np.asarray(point, dtype=float))

    def add(self) -> None:
        scene = self.scene
        world = self.spec.worldbody
        rotation = self.world_from_base.rotation
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
        x0, y0, x1, y1 = scene.table_xy_m
        top = scene.table_top_z_m
        world.add_geom(name=TABLE_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX,
                       pos=self._to_world(((x0 + x1) / 2, (y0 + y1) / 2, top - scene.table_thickness_m / 2)),
                       quat=quat, size=[(x1 - x0) / 2, (y1 - y0) / 2, scene.table_thickness_m / 2],
                       friction=[scene.table_friction, 0.005, 0.0001], rgba=[0.55, 0.42, 0.3, 1.0])
        world.add_geom(name=FLOOR_GEOM, type=mujoco.mjtGeom.mjGEOM_PLANE,
                       pos=self._to_world((0.0, 0.0, top - scene.table_height_m)), quat=quat,
                       size=[0, 0, 0.05], rgba=[0.8, 0.8, 0.8, 1.0])
        world.add_light(name="key", pos=self._to_world((0.5, -1.0, 2.5)), dir=rotation @ np.array([-0.2, 0.4, -1.0]),
                        diffuse=[0.7, 0.7, 0.7], castshadow=True)
        world.add_light(name="fill", pos=self._to_world((-1.0, 1.0, 2.0)), dir=rotation @ np.array([0.4, -0.4, -1.0]),
                        diffuse=[0.3, 0.3, 0.3], castshadow=False)
        for camera in scene.cameras:
            self._add_camera(camera)
        for item in scene.objects:
            self._add_object(item)

    def _add_object(self, item: SceneObject) -> None:
        if item.shape not in ("box", "cylinder"):
            raise RobotModelError(f"scene object {item.name!r}: shape must be 'box' or 'cylinder', not {item.shape!r}")
        rotation = self.world_from_base.rotation @ pin.utils.rpyToMatrix(0.0, 0.0, item.yaw_rad)
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
        body = self.spec.worldbody.add_body(name=item.name, pos=self._to_world(item.position_m), quat=quat)
        if not item.fixed:
            body.add_freejoint(name=item.name)
        if item.shape == "box":
            shape, size = mujoco.mjtGeom.mjGEOM_BOX, [v / 2.0 for v in item.size_m]
        else:
            shape, size = mujoco.mjtGeom.mjGEOM_CYLINDER, [item.size_m[0] / 2.0, item.size_m[2] / 2.0, 0.0]
        body.add_geom(name=item.name, type=shape, size=size, mass=item.mass_kg, condim=4,
                      friction=[item.friction, 0.02, 0.001], rgba=list(item.rgba))

    def _add_camera(self, camera: CameraSpec) -> None:
        position = np.asarray(camera.position_m, dtype=float)
        target = np.asarray(camera.target_m, dtype=float)
        up = np.asarray(camera.up, dtype=float)
        if camera.body is None:
            body = self.spec.worldbody
            position, target = self._to_world(position), self._to_world(target)
            up = self.world_from_base.rotation @ up
        else:
            body = self.spec.body(camera.body)
            if body is None:
                raise RobotModelError(f"camera {camera.name!r}: MuJoCo has no body {camera.body!r}")
        body.add_camera(name=camera.name, pos=position, quat=look_at_quat(position, target, up), fovy=camera.fovy_deg)


__all__ = ["SceneObject", "SceneSpec", "add_cell", "scene_for_policy"]
