"""The `motion` and `force` sections: caps on planned motion and the contact-force monitor."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any, Literal

from pydantic import BaseModel, Field, model_validator

from armwarden.policy.constants import DEFAULT_SCALING
from armwarden.policy.fields import MODEL_CONFIG, StrictBool, Violation, enforce, finite
from armwarden.policy.joint_torques import JointTorqueConfig

#: Largest hard cap on one joint's travel per plan [rad]: half a turn. A larger cap lets one
#: plan swing a joint through most of its range without any human seeing it first.
MAX_JOINT_STEP_RAD = round(math.pi, 4)
#: Largest hard cap on the TCP path of one plan [m]; larger caps limit nothing in a cell whose
#: coordinates are bounded by ±5 m.
MAX_CARTESIAN_STEP_M = 5.0
#: Largest start tolerance [rad]. The bundled policy uses 0.01 and the fake backend's own check
#: 0.05; a plan whose start is further from the arm than this was planned from elsewhere, and a
#: large tolerance (10 rad) would switch the start-state check off.
MAX_START_TOLERANCE_RAD = 0.1
#: Resolution bounds. Coarser than the upper bound and the check between samples says little;
#: finer than the lower bound and one plan needs millions of kinematics evaluations (the daemon
#: would hang in planning instead of answering).
MIN_CHECK_RESOLUTION_RAD, MAX_CHECK_RESOLUTION_RAD = 0.001, 0.1
MIN_SWEEP_RESOLUTION_M, MAX_SWEEP_RESOLUTION_M = 0.001, 0.05
#: Longest planning budget [s]. Plans and every execution's last envelope re-check share one
#: planning thread, so a longer search would hold the next execute_plan back by as much.
MAX_PLANNING_TIME_S = 2.0


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
    max_joint_step_rad: float = finite(
        gt=0,
        le=MAX_JOINT_STEP_RAD,
        description=f"Hard cap on any joint's travel in one plan [rad], in (0, {MAX_JOINT_STEP_RAD:g}].",
    )
    soft_joint_step_rad: float | None = finite(
        gt=0,
        default=None,
        description="Joint travel in one plan [rad] above which approval is needed; ≤ max_joint_step_rad. "
        "Null: no soft threshold.",
    )
    max_cartesian_step_m: float = finite(
        gt=0,
        le=MAX_CARTESIAN_STEP_M,
        description=f"Hard cap on the TCP path length of one plan [m], in (0, {MAX_CARTESIAN_STEP_M:g}].",
    )
    plan_ttl_s: float = finite(gt=0, le=3600, default=120, description="Plan lifetime [s], in (0, 3600].")
    joint_limit_margin_rad: float = finite(
        ge=0, default=0.05, description="Distance to a joint limit [rad] below which a plan needs approval."
    )
    start_tolerance_rad: float = finite(
        gt=0,
        le=MAX_START_TOLERANCE_RAD,
        default=0.01,
        description="Largest joint deviation [rad] from a plan's start state at execution, "
        f"in (0, {MAX_START_TOLERANCE_RAD:g}].",
    )
    check_resolution_rad: float = finite(
        ge=MIN_CHECK_RESOLUTION_RAD,
        le=MAX_CHECK_RESOLUTION_RAD,
        default=0.02,
        description="Largest joint step [rad] between configurations the planner checks, "
        f"in [{MIN_CHECK_RESOLUTION_RAD:g}, {MAX_CHECK_RESOLUTION_RAD:g}].",
    )
    sweep_resolution_m: float = finite(
        ge=MIN_SWEEP_RESOLUTION_M,
        le=MAX_SWEEP_RESOLUTION_M,
        default=0.01,
        description="Largest displacement [m] of any checked body between envelope samples, "
        f"in [{MIN_SWEEP_RESOLUTION_M:g}, {MAX_SWEEP_RESOLUTION_M:g}].",
    )
    planning_time_s: float = finite(
        gt=0,
        le=MAX_PLANNING_TIME_S,
        default=0.5,
        description="Time budget [s] for finding a detour when the straight line is blocked (other IK "
        f"solutions, then a joint-space search), in (0, {MAX_PLANNING_TIME_S:g}]; out of budget the plan is "
        "rejected with NO_DETOUR.",
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


#: Largest contact-force limit [N]. ISO/TS 15066 puts the quasi-static contact limits for the
#: body regions at 65–220 N; a limit above 150 N would not stop the arm before it hurts most of
#: them, and 10 kN (a typo, or "no limit") would never stop it.
MAX_CONTACT_FORCE_N = 150.0
#: Largest contact-torque limit [N·m] (the bundled FR3 policy uses 10).
MAX_CONTACT_TORQUE_NM = 30.0
#: Slowest force monitor [Hz]: at 10 Hz a contact goes unchecked for up to 100 ms.
MIN_MONITOR_RATE_HZ = 10.0
#: Oldest wrench sample the monitor may accept [s].
MAX_WRENCH_TIMEOUT_S = 0.5


class ForceConfig(BaseModel):
    """Contact monitoring while a trajectory runs. Over a limit: stop and latch the e-stop.

    The contact is measured by a force/torque sensor at the tool, or estimated from the joint
    torques the motors measure (`joint_torques`); `source` says which."""

    model_config = MODEL_CONFIG

    max_contact_force_n: float = finite(
        gt=0,
        le=MAX_CONTACT_FORCE_N,
        description=f"Largest external force at the TCP [N] (vector norm), in (0, {MAX_CONTACT_FORCE_N:g}].",
    )
    max_contact_torque_nm: float = finite(
        gt=0,
        le=MAX_CONTACT_TORQUE_NM,
        description=f"Largest external torque at the TCP [N·m] (vector norm), in (0, {MAX_CONTACT_TORQUE_NM:g}].",
    )
    monitor_rate_hz: float = finite(
        ge=MIN_MONITOR_RATE_HZ,
        le=5000,
        default=200,
        description=f"Wrench polling rate [Hz], in [{MIN_MONITOR_RATE_HZ:g}, 5000]; its period must not exceed "
        "wrench_timeout_s.",
    )
    require_wrench: StrictBool = Field(
        default=True,
        description="Refuse to execute without a wrench signal (boolean). False runs without force enforcement.",
    )
    wrench_timeout_s: float = finite(
        gt=0,
        le=MAX_WRENCH_TIMEOUT_S,
        default=0.1,
        description=f"Oldest acceptable wrench sample [s], in (0, {MAX_WRENCH_TIMEOUT_S:g}]; older aborts the motion. "
        "With source joint_torques: the oldest acceptable joint state.",
    )
    source: Literal["auto", "sensor", "joint_torques"] = Field(
        default="auto",
        description="What measures the contact (no unit): `sensor` (the backend's force/torque sensor or its own "
        "wrench estimate), `joint_torques` (the observer over the torques the motors measure; needs the "
        "joint_torques section), or `auto` (the sensor where the backend has one, else the joint torques where it "
        "measures them and the section is given). Neither: NO_WRENCH.",
    )
    joint_torques: JointTorqueConfig | None = Field(
        default=None,
        description="Contact limits on the external joint torques estimated from measured joint torques "
        "(N·m per joint), the friction the estimate allows for, and the payload; required by source joint_torques.",
    )

    @model_validator(mode="after")
    def _rules(self) -> ForceConfig:
        enforce([self._monitor_period_within_wrench_timeout(), self._joint_torque_source_has_limits(),
                 self._estimated_force_within_contact_force()])
        return self

    def _estimated_force_within_contact_force(self) -> Iterator[Violation]:
        """The estimate's own limit tightens the contact force limit; it never loosens it."""
        estimated = None if self.joint_torques is None else self.joint_torques.max_tcp_force_n
        if estimated is not None and estimated > self.max_contact_force_n:
            yield ("joint_torques", "max_tcp_force_n"), (
                f"{estimated:g} N is above max_contact_force_n ({self.max_contact_force_n:g} N): the estimate's "
                "limit may only be lower")

    @property
    def estimated_force_limit_n(self) -> float:
        """The TCP force limit [N] for a force estimated from joint torques."""
        estimated = None if self.joint_torques is None else self.joint_torques.max_tcp_force_n
        return self.max_contact_force_n if estimated is None else estimated

    def _joint_torque_source_has_limits(self) -> Iterator[Violation]:
        """Joint torques without limits would estimate the contact and stop at nothing."""
        if self.source == "joint_torques" and self.joint_torques is None:
            yield ("joint_torques",), ("source joint_torques needs the joint_torques section (max_external_torque_nm "
                                       "per joint); `armwarden calibrate-contact` recommends values")

    def _monitor_period_within_wrench_timeout(self) -> Iterator[Violation]:
        """Between two polls nothing is checked: a period longer than the staleness timeout hides contact.

        (With `monitor_rate_hz: 0.001` an arm pressed 999 N into a table during one motion while the
        monitor slept.)
        """
        period_s = 1.0 / self.monitor_rate_hz
        if period_s > self.wrench_timeout_s:
            yield ("monitor_rate_hz",), (
                f"monitor_rate_hz ({self.monitor_rate_hz:g}) polls every {period_s:g} s, longer than "
                f"wrench_timeout_s ({self.wrench_timeout_s:g} s): contact between polls would go unchecked; "
                f"poll at least {1.0 / self.wrench_timeout_s:g} Hz"
            )

