"""Per-model value ranges of CAN actuators, as validated data.

The ranges are firmware/model settings, not protocol constants: both the MIT-mode command and
the RobStride operation-control frame map each float onto an unsigned integer over the model's
range, so a value is only meaningful together with the model it was packed for. Look a model up
with `model_ranges(name)`; an unknown name is a configuration error that lists the known ones.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from armwarden.backends.can.errors import UnknownModel


class Protocol(str, enum.Enum):
    """The wire protocol an actuator speaks."""

    MIT = "mit"  # Mini-Cheetah style MIT mode (CubeMars AK), 11-bit ids
    ROBSTRIDE = "robstride"  # RobStride private protocol, 29-bit ids


@dataclass(frozen=True)
class Range:
    """A closed interval [lo, hi] of finite values with lo < hi."""

    lo: float
    hi: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)):
            raise ValueError(f"range bounds must be finite, got [{self.lo}, {self.hi}]")
        if not self.lo < self.hi:
            raise ValueError(f"range must have lo < hi, got [{self.lo}, {self.hi}]")

    @property
    def span(self) -> float:
        return self.hi - self.lo

    def __contains__(self, value: object) -> bool:
        return isinstance(value, (int, float)) and self.lo <= value <= self.hi


@dataclass(frozen=True)
class ModelRanges:
    """The ranges one actuator model maps its command and feedback values over.

    `position` [rad], `velocity` [rad/s], `kp` [N·m/rad], `kd` [N·m·s/rad], `torque` [N·m].
    """

    model: str
    protocol: Protocol
    position: Range
    velocity: Range
    kp: Range
    kd: Range
    torque: Range

    def __post_init__(self) -> None:
        if not self.model:
            raise ValueError("model name must not be empty")
        for gain in ("kp", "kd"):
            if getattr(self, gain).lo != 0.0:
                raise ValueError(f"{self.model}: {gain} range must start at 0, got {getattr(self, gain)}")


def _sym(limit: float) -> Range:
    return Range(-limit, limit)


def _mit(model: str, v_max: float, t_max: float) -> ModelRanges:
    return ModelRanges(model, Protocol.MIT, _sym(12.5), _sym(v_max), Range(0.0, 500.0), Range(0.0, 5.0), _sym(t_max))


def _robstride(model: str, v_max: float, t_max: float, kp_max: float, kd_max: float) -> ModelRanges:
    return ModelRanges(
        model, Protocol.ROBSTRIDE, _sym(4 * math.pi), _sym(v_max), Range(0.0, kp_max), Range(0.0, kd_max), _sym(t_max)
    )


#: every known model by name (read-only)
MODELS: Mapping[str, ModelRanges] = MappingProxyType({
    r.model: r
    for r in (
        _mit("AK80-9", 50.0, 18.0),
        _mit("AK70-10", 50.0, 25.0),
        _mit("AK10-9", 50.0, 65.0),
        _mit("AK80-6", 76.0, 12.0),
        _robstride("RS00", 33.0, 14.0, 500.0, 5.0),
        _robstride("RS01", 44.0, 17.0, 500.0, 5.0),
        _robstride("RS02", 44.0, 17.0, 500.0, 5.0),
        _robstride("RS03", 20.0, 60.0, 5000.0, 100.0),
        _robstride("RS04", 15.0, 120.0, 5000.0, 100.0),
        _robstride("RS05", 50.0, 5.5, 500.0, 5.0),
        _robstride("RS06", 50.0, 36.0, 5000.0, 100.0),
    )
})


def model_ranges(model: str) -> ModelRanges:
    """The ranges of `model`; `UnknownModel` (naming the known models) if there are none."""
    try:
        return MODELS[model]
    except KeyError:
        raise UnknownModel(f"unknown actuator model {model!r}; known models: {', '.join(MODELS)}") from None


__all__ = ["MODELS", "ModelRanges", "Protocol", "Range", "model_ranges"]
