"""The `Policy` model: the whole document, its sections and the rules that span sections."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Literal

from pydantic import BaseModel, Field, field_validator, model_validator

from armwarden.policy.access import ApprovalConfig, RateLimitsConfig, ToolsConfig
from armwarden.policy.devices import ControllersConfig, GripperConfig, PerceptionConfig
from armwarden.policy.fields import MODEL_CONFIG, StrictBool, Violation, enforce
from armwarden.policy.messages import show_value
from armwarden.policy.motion import ForceConfig, MotionConfig
from armwarden.policy.robot import RobotConfig
from armwarden.policy.workspace import WorkspaceConfig


class Policy(BaseModel):
    """ArmWarden safety policy, version 1. Loaded once, validated strictly, immutable."""

    model_config = MODEL_CONFIG

    version: Literal[1] = Field(description="Policy format version (no unit); must be 1.")
    robot: RobotConfig = Field(description="The arm, its frames, joints and joint limits.")
    tools: ToolsConfig = Field(default_factory=ToolsConfig, description="Enabled tool groups.")
    workspace: WorkspaceConfig = Field(description="Workspace box and keep-out zones (metres, base frame).")
    motion: MotionConfig = Field(description="Motion caps (scalings, joint/Cartesian steps, timing, resolutions).")
    force: ForceConfig = Field(description="Contact force/torque limits (N, N·m) and monitoring.")
    gripper: GripperConfig | None = Field(
        default=None, description="Gripper bounds (m, N, m/s); required when the gripper group is enabled."
    )
    controllers: ControllersConfig = Field(default_factory=ControllersConfig, description="Controller allowlist.")
    perception: PerceptionConfig = Field(default_factory=PerceptionConfig, description="Camera allowlist, image size.")
    rate_limits: RateLimitsConfig = Field(default_factory=RateLimitsConfig, description="Rate limits [1/min].")
    approval: ApprovalConfig = Field(default_factory=ApprovalConfig, description="Human approval rules.")
    dry_run: StrictBool = Field(default=False, description="Validate and ask, but never actuate (boolean).")

    @field_validator("version", mode="before")
    @classmethod
    def _version_is_an_integer(cls, value: Any) -> Any:
        """`Literal[1]` alone would accept `true` and `1.0`; the version must be the integer 1."""
        if type(value) is not int:
            raise ValueError(f"version must be the integer 1 (got {show_value(value)})")
        return value

    @model_validator(mode="after")
    def _rules(self) -> Policy:
        enforce(
            [
                self._gripper_section_when_gripper_enabled(),
                self._limit_margin_leaves_room(),
                self._outside_envelope_approval_has_something_to_ask_about(),
                self._joint_torque_limits_cover_joints(),
            ]
        )
        return self

    def _gripper_section_when_gripper_enabled(self) -> Iterator[Violation]:
        """Gripper tools without bounds would be unbounded; refuse rather than guess."""
        if "gripper" in self.tools.enabled and self.gripper is None:
            yield ("gripper",), "the gripper tool group is enabled, so the gripper section is required"

    def _limit_margin_leaves_room(self) -> Iterator[Violation]:
        """A margin of half a joint's range or more would flag every position of that joint."""
        for name, limits in self.robot.joint_limits.items():
            if 2 * self.motion.joint_limit_margin_rad >= limits.max - limits.min:
                yield ("motion", "joint_limit_margin_rad"), (
                    f"joint_limit_margin_rad ({self.motion.joint_limit_margin_rad:g}) leaves no room in the range "
                    f"of {name} [{limits.min:g}, {limits.max:g}]"
                )

    def _outside_envelope_approval_has_something_to_ask_about(self) -> Iterator[Violation]:
        """`outside_envelope` asks only on soft violations; with none configured it silently never asks."""
        motion = self.motion
        if (
            self.approval.mode == "outside_envelope"
            and motion.soft_joint_step_rad is None
            and motion.joint_limit_margin_rad == 0
        ):
            yield ("approval", "mode"), (
                "mode outside_envelope asks a human only about soft violations, but motion configures none "
                "(soft_joint_step_rad is null and joint_limit_margin_rad is 0), so it would never ask: set one "
                "of them, or write mode: never if that is what you mean"
            )

    def _joint_torque_limits_cover_joints(self) -> Iterator[Violation]:
        """A driven joint without an external-torque limit would be unwatched; an unknown name is a typo."""
        section = self.force.joint_torques
        if section is not None:
            for path, message in section.coverage_violations(self.robot.joint_names):
                yield ("force", "joint_torques", *path), message

    @property
    def enabled_tools(self) -> tuple[str, ...]:
        """Every tool name of the enabled groups (before backend capabilities are considered)."""
        return self.tools.tools

    def with_dry_run(self, enabled: bool = True) -> Policy:
        """A copy with dry run forced on when `enabled` (the `--dry-run` flag).

        `with_dry_run(False)` never turns off a dry run the policy file asked for: the flag can
        only make the daemon safer, so `policy.with_dry_run(args.dry_run)` is always correct.
        """
        if not enabled or self.dry_run:
            return self
        return self.model_copy(update={"dry_run": True})

