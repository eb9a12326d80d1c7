"""Violation codes and the Violation record every safety check returns.

Hard violations reject a plan outright: no approval can override them. Soft ones mark it as
outside the envelope, which asks a human in `outside_envelope` approval mode.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Severity(str, Enum):
    HARD = "hard"
    SOFT = "soft"


class Code(str, Enum):
    JOINT_LIMIT = "JOINT_LIMIT"
    NEAR_JOINT_LIMIT = "NEAR_JOINT_LIMIT"
    WORKSPACE = "WORKSPACE"
    KEEP_OUT = "KEEP_OUT"
    SELF_COLLISION = "SELF_COLLISION"
    STEP_TOO_LARGE = "STEP_TOO_LARGE"
    LARGE_MOTION = "LARGE_MOTION"
    CARTESIAN_STEP_TOO_LARGE = "CARTESIAN_STEP_TOO_LARGE"
    VELOCITY_LIMIT = "VELOCITY_LIMIT"
    ACCELERATION_LIMIT = "ACCELERATION_LIMIT"
    MALFORMED = "MALFORMED"
    IK_FAILED = "IK_FAILED"
    NO_DETOUR = "NO_DETOUR"  # the straight line is blocked and the planner found no safe way around in time


SOFT_CODES = frozenset({Code.NEAR_JOINT_LIMIT, Code.LARGE_MOTION})


@dataclass(frozen=True)
class Violation:
    """One finding: what, how bad, where in time (s from plan start) and on which body."""

    code: Code
    detail: str
    time_s: float | None = None
    body: str | None = None

    @property
    def severity(self) -> Severity:
        return Severity.SOFT if self.code in SOFT_CODES else Severity.HARD

    @property
    def is_hard(self) -> bool:
        return self.severity is Severity.HARD


def has_hard(violations: list[Violation] | tuple[Violation, ...]) -> bool:
    return any(v.is_hard for v in violations)
