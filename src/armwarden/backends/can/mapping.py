"""Float <-> unsigned-integer mapping over a value range (the encoding both protocols use).

`encode` truncates `(x − lo)·(2^bits − 1)/(hi − lo)` to an integer, as the firmware's reference
code does (the golden vectors depend on it), so `decode(encode(x))` lies within one LSB below x.
Zero is usually not exactly representable: compare decoded values with `lsb(...)` tolerance.

Refuse, don't clamp: `encode` raises `ValueError` for NaN/Inf and for values outside the range.
Deciding what to command is the servo layer's job; a codec that clamped would silently send a
different command than the one that was checked.
"""

from __future__ import annotations

import math

from armwarden.backends.can.ranges import Range


def _full_scale(bits: int) -> int:
    if not 1 <= bits <= 32:
        raise ValueError(f"bits must be in 1..32, got {bits}")
    return (1 << bits) - 1


def lsb(value_range: Range, bits: int) -> float:
    """The value of one least significant bit of a `bits`-wide field over `value_range`."""
    return value_range.span / _full_scale(bits)


def encode(value: float, value_range: Range, bits: int, field: str) -> int:
    """`value` as a `bits`-wide unsigned integer over `value_range`; `ValueError` naming `field`
    and its range if it is not a finite number inside the range."""
    full = _full_scale(bits)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{field} must be a finite number, got {value!r}")
    if not value_range.lo <= value <= value_range.hi:
        raise ValueError(f"{field} = {value} is outside its range [{value_range.lo}, {value_range.hi}]")
    scaled = (float(value) - value_range.lo) * full / value_range.span
    return min(int(scaled), full)  # rounding error must not push hi past the field's full scale


def decode(raw: int, value_range: Range, bits: int) -> float:
    """The value a `bits`-wide unsigned integer stands for over `value_range`."""
    full = _full_scale(bits)
    if not 0 <= raw <= full:
        raise ValueError(f"raw value {raw} does not fit in {bits} bits")
    return raw * value_range.span / full + value_range.lo


__all__ = ["decode", "encode", "lsb"]
