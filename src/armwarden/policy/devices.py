"""The `gripper`, `controllers` and `perception` sections: what the optional devices may do."""

from __future__ import annotations

from collections.abc import Iterator

from pydantic import BaseModel, Field, model_validator

from armwarden.policy.fields import MODEL_CONFIG, UniqueNames, Violation, enforce, finite

#: Widest opening a policy may allow [m] (the Franka Hand opens 0.08 m; long-stroke parallel
#: grippers about 0.14 m).
MAX_GRIPPER_WIDTH_M = 0.5
#: Largest grasp force [N] (Franka Hand: 70 N continuous; common parallel grippers stay below
#: 250 N). More is a typo or no limit at all.
MAX_GRASP_FORCE_N = 250.0
#: Fastest finger speed [m/s] (common parallel grippers: 0.05–0.15).
MAX_FINGER_SPEED_MPS = 0.5
#: the slowest finger speed a call may ask [m/s]: a full 0.2 m stroke then takes 200 s; slower
#: would let one call hold the gripper (and every other gripper call) for hours
MIN_FINGER_SPEED_MPS = 0.001


class GripperConfig(BaseModel):
    """Gripper bounds; required when the `gripper` tool group is enabled."""

    model_config = MODEL_CONFIG

    min_width_m: float = finite(ge=0, default=0.0, description="Narrowest commanded opening [m].")
    max_width_m: float = finite(
        gt=0,
        le=MAX_GRIPPER_WIDTH_M,
        description=f"Widest commanded opening [m], in (0, {MAX_GRIPPER_WIDTH_M:g}]; greater than min_width_m.",
    )
    max_grasp_force_n: float = finite(
        gt=0, le=MAX_GRASP_FORCE_N, description=f"Largest grasp force [N], in (0, {MAX_GRASP_FORCE_N:g}]."
    )
    max_speed_mps: float = finite(
        ge=MIN_FINGER_SPEED_MPS, le=MAX_FINGER_SPEED_MPS,
        description=f"Largest finger speed [m/s], in [{MIN_FINGER_SPEED_MPS:g}, {MAX_FINGER_SPEED_MPS:g}].",
    )

    @model_validator(mode="after")
    def _rules(self) -> GripperConfig:
        enforce([self._width_range_not_empty()])
        return self

    def _width_range_not_empty(self) -> Iterator[Violation]:
        if not self.max_width_m > self.min_width_m:
            yield ("max_width_m",), (
                f"max_width_m ({self.max_width_m:g}) must be greater than min_width_m ({self.min_width_m:g})"
            )


class ControllersConfig(BaseModel):
    """Controllers `switch_controllers` may activate; anything else is refused."""

    model_config = MODEL_CONFIG

    allowlist: UniqueNames = Field(default=(), description="Controller names (no unit) that may be activated.")


class PerceptionConfig(BaseModel):
    """Cameras `camera_snapshot` may read, and how large an image may be."""

    model_config = MODEL_CONFIG

    cameras: UniqueNames = Field(default=(), description="Camera names (no unit) that may be read.")
    max_image_width: int = Field(
        default=640, strict=True, ge=16, le=4096, description="Largest returned image width [pixels], 16..4096."
    )

