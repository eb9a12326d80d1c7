"""`--backend-config` for the MuJoCo backend: the physics step, the speed-up, the table, the
cameras and loose objects. Strict (extra keys refused), frozen, units in every name; the backend
module (`armwarden.backends.mujoco.backend`) takes it in `create_backend`."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from armwarden.backends.mujoco.camera_mounts import CameraSpec
from armwarden.backends.mujoco.scene import SceneObject

Vector3 = tuple[float, float, float]


class CameraConfig(BaseModel):
    """A named camera: in the base frame (no `body`) or on a body, looking from `position_m` at `target_m`."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str = Field(min_length=1, description="Camera name, as `camera_snapshot` takes it.")
    position_m: Vector3 = Field(description="Camera position [m] in the base frame, or in `body`'s frame.")
    target_m: Vector3 = Field(description="Point the camera looks at [m], same frame.")
    body: str | None = Field(default=None, description="Body the camera rides on (e.g. the hand); null: fixed in the cell.")
    up: Vector3 = Field(default=(0.0, 0.0, 1.0), description="Up direction of the image, no unit, same frame.")
    fovy_deg: float = Field(default=45.0, gt=0, lt=180, allow_inf_nan=False, description="Vertical field of view [deg].")

    def spec(self) -> CameraSpec:
        return CameraSpec(self.name, self.position_m, self.target_m, self.body, self.up, self.fovy_deg)


class ObjectConfig(BaseModel):
    """A rigid object in the cell, loose or fixed: a box, or an upright cylinder."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    name: str = Field(min_length=1, description="Body name of the object.")
    shape: Literal["box", "cylinder"] = Field(description="'box' or 'cylinder'.")
    position_m: Vector3 = Field(description="Centre [m] in the base frame.")
    size_m: Vector3 = Field(description="Box: full extents (x, y, z) [m]; cylinder: (diameter, unused, height) [m].")
    mass_kg: float = Field(gt=0, description="Mass [kg].")
    yaw_rad: float = Field(default=0.0, description="Rotation about the vertical [rad].")
    friction: float = Field(default=1.0, gt=0, description="Sliding friction coefficient, no unit.")
    fixed: bool = Field(default=False, description="Welded to the world (an obstacle that never moves); false: loose.")

    def spec(self) -> SceneObject:
        return SceneObject(self.name, self.shape, self.position_m, self.size_m, self.mass_kg, self.yaw_rad, self.friction,
                           fixed=self.fixed)


class Config(BaseModel):
    """`--backend-config` for the MuJoCo backend (strict, like every config file)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    timestep_s: float = Field(default=0.001, gt=0, le=0.005, allow_inf_nan=False, description="Physics step [s].")
    speedup: float = Field(default=1.0, gt=0, le=100, allow_inf_nan=False,
                           description="Simulated time per wall time, no unit (2 = twice as fast as real time).")
    table_top_z_m: float | None = Field(
        default=None, allow_inf_nan=False,
        description="Height of the table top [m] in the base frame; null: the policy's workspace floor.",
    )
    cameras: tuple[CameraConfig, ...] | None = Field(
        default=None, description="Named cameras; null: the robot profile's mounts (a user URDF must list them)."
    )
    camera_width_px: int = Field(default=640, ge=16, le=1280, description="Rendered image width [px].")
    camera_height_px: int = Field(default=480, ge=16, le=960, description="Rendered image height [px].")
    objects: tuple[ObjectConfig, ...] = Field(default=(), description="Objects in the cell (loose, or fixed).")


__all__ = ["CameraConfig", "Config", "ObjectConfig", "Vector3"]
