"""The `motion` and `force` sections: caps on planned motion and the contact-force monitor."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any, Optional

from pydantic import BaseModel, Field, model_validator

from armwarden.policy.constants import DEFAULT_SCALING
from armwarden.policy.fields import MODEL_CONFIG, StrictBool, Violation, enforce, finite


class MotionConfig(BaseModel):
    """Caps on planned motion. Scalings multiply the joint velocity/acceleration limits."""

    model_config = MODEL_CONFIG

    max_velocity_scaling: float = finite(
        gt=0, le=1, description="Cap on velocity scaling (fraction of joint max_velocity, in (0, 1])."
    )
    max_acceleration_scaling: float = finite(
        gt=0, le=1, description="Cap on acceleration scaling (fraction of joint max_acceleration, in (0, 1])."
    )
    default_velocity_scaling: float = finite(
        gt=0,
        le=1,
        default=DEFAULT_SCALING,
        description="Velocity scaling (fraction, in (0, 1]) used when a request gives none; ≤ the cap. "
        "Default 0.1, or the cap if that is lower.",
    )
    default_acceleration_scaling: float = finite(
        gt=0,
        le=1,
        default=DEFAULT_SCALING,
        description="Acceleration scaling (fraction, in (0, 1]) used when a request gives none; ≤ the cap. "
        "Default 0.1, or the cap if that is lower.",
    )
    max_joint_step_rad: float = finite(gt=0, description="Hard cap on any joint's travel in one plan [rad].")
    soft_joint_step_rad: Optional[float] = finite(
        gt=0,
        default=None,
        description="Joint travel in one plan [rad] above which approval is needed; ≤ max_joint_step_rad. "
        "Null: no soft threshold.",
    )
    max_cartesian_step_m: float = finite(gt=0, description="Hard cap on the TCP path length of one plan [m].")
    plan_ttl_s: float = finite(gt=0, le=3600, default=120, description="Plan lifetime [s], in (0, 3600].")
    joint_limit_margin_rad: float = finite(
        ge=0, default=0.05, description="Distance to a joint limit [rad] below which a plan needs approval."
    )
    start_tolerance_rad: float = finite(
        gt=0, default=0.01, description="Largest joint deviation [rad] from a plan's start state at execution."
    )
    check_resolution_rad: float = finite(
        gt=0, default=0.02, description="Largest joint step [rad] between configurations the planner checks."
    )
    sweep_resolution_m: float = finite(
        gt=0,
        le=0.05,
        default=0.01,
        description="Largest displacement [m] of any checked body between envelope samples, in (0, 0.05].",
    )

    @model_validator(mode="before")
    @classmethod
    def _default_scalings_follow_low_caps(cls, data: Any) -> Any:
        """An omitted default scaling is 0.1, lowered to the cap when the cap is below 0.1.

        Writing only a (low) cap is the natural way to make a policy more conservative; it should
        not fail because of a default the author never wrote. An explicit default above the cap is
        still an error.
        """
        if not isinstance(data, Mapping):
            return data
        data = dict(data)
        for default_key, cap_key in (
            ("default_velocity_scaling", "max_velocity_scaling"),
            ("default_acceleration_scaling", "max_acceleration_scaling"),
        ):
            cap = data.get(cap_key)
            if (
                default_key not in data
                and isinstance(cap, (int, float))
                and not isinstance(cap, bool)
                and math.isfinite(cap)
                and 0 < cap < DEFAULT_SCALING
            ):
                data[default_key] = cap
        return data

    @model_validator(mode="after")
    def _rules(self) -> MotionConfig:
        enforce([self._defaults_within_caps(), self._soft_step_within_hard_step()])
        return self

    def _defaults_within_caps(self) -> Iterator[Violation]:
        """Above-cap requests are clamped to the cap; a default above it would be clamped on every call."""
        for default_key, cap_key in (
            ("default_velocity_scaling", "max_velocity_scaling"),
            ("default_acceleration_scaling", "max_acceleration_scaling"),
        ):
            default, cap = getattr(self, default_key), getattr(self, cap_key)
            if default > cap:
                yield (default_key,), f"{default_key} ({default:g}) must not exceed {cap_key} ({cap:g})"

    def _soft_step_within_hard_step(self) -> Iterator[Violation]:
        """A soft threshold above the hard cap could never trigger: the plan is rejected first."""
        if self.soft_joint_step_rad is not None and self.soft_joint_step_rad > self.max_joint_step_rad:
            yield ("soft_joint_step_rad",), (
                f"soft_joint_step_rad ({self.soft_joint_step_rad:g}) must not exceed "
                f"max_joint_step_rad ({self.max_joint_step_rad:g})"
            )


class ForceConfig(BaseModel):
    """Contact-force monitoring while a trajectory runs. Over the limit: stop and latch the e-stop."""

    model_config = MODEL_CONFIG

    max_contact_force_n: float = finite(gt=0, description="Largest external force at the TCP [N] (vector norm).")
    max_contact_torque_nm: float = finite(gt=0, description="Largest external torque at the TCP [N·m] (vector norm).")
    monitor_rate_hz: float = finite(gt=0, le=5000, default=200, description="Wrench polling rate [Hz], in (0, 5000].")
    require_wrench: StrictBool = Field(
        default=True,
        description="Refuse to execute without a wrench signal (boolean). False runs without force enforcement.",
    )
    wrench_timeout_s: float = finite(
        gt=0, le=2, default=0.1, description="Oldest acceptable wrench sample [s], in (0, 2]; older aborts the motion."
    )

