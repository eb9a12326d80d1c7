"""The fake backend's `--backend-config` schema: strict, like every config file."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class Config(BaseModel):
    """`--backend-config` for the fake backend (strict, like every config file)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    speedup: float = Field(default=1.0, gt=0, le=1000, description="Time scaling of execution, no unit (2 = twice as fast).")
    table_height_m: float | None = Field(
        default=None, allow_inf_nan=False, description="Height [m] of a virtual table plane producing contact force; null: none."
    )
    table_stiffness_n_per_m: float = Field(
        default=20000.0, gt=0, allow_inf_nan=False, description="Stiffness of the virtual table [N/m]."
    )
    wrench: bool = Field(default=True, description="Provide an external wrench estimate (boolean).")
    joint_torques: bool = Field(
        default=True, description="Joint states carry measured joint torques, the model's own (boolean)."
    )
    joint_torque_noise_nm: float = Field(
        default=0.0, ge=0, le=100, allow_inf_nan=False,
        description="Standard deviation [N·m] of Gaussian noise on the measured joint torques (0: none).",
    )
    joint_torque_noise_seed: int = Field(default=0, description="Seed of that noise (runs repeat exactly).")


__all__ = ["Config"]
