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

#: 2^bits − 1 for every field width the protocols use (and any up to 32)
_FULL_SCALE = {bits: (1 << bits) - 1 for bits in range(1, 33)}


def _full_scale(bits: int) -> int:
    full = _FULL_SCALE.get(bits)
    if full is None:
        raise ValueError(f"bits must be in 1..32, got {bits}")
    return full


def lsb(value_range: Range, bits: int) -> float:
    """The value of one least significant bit of a `bits`-wide field over `value_range`."""
    return value_range.span / _full_scale(bits)


def encode(value: float, value_range: Range, bits: int, field: str) -> int:
    """`value` as a `bits`-wide unsigned integer over `value_range`; `ValueError` naming `field`
    and its range if it is not a finite number inside the range."""
    full = _full_scale(bits)
    # the servo loop encodes thousands of fields a second: the common case (a float) is checked first
    if value.__class__ is not float and (isinstance(value, bool) or not isinstance(value, (int, float))):
        raise ValueError(f"{field} must be a finite number, got {value!r}")
    lo, hi = value_range.lo, value_range.hi
    if not lo <= value <= hi:  # NaN and ±Inf fail this comparison too
        if not math.isfinite(value):
            raise ValueError(f"{field} must be a finite number, got {value!r}")
        raise ValueError(f"{field} = {value} is outside its range [{lo}, {hi}]")
    scaled = (float(value) - lo) * full / (hi - lo)
    return min(int(scaled), full)  # rounding error must not push hi past the field's full scale


def decode(raw: int, value_range: Range, bits: int) -> float:
    """The value a `bits`-wide unsigned integer stands for over `value_range`."""
    full = _full_scale(bits)
    if not 0 <= raw <= full:
        raise ValueError(f"raw value {raw} does not fit in {bits} bits")
    lo = value_range.lo
    return raw * (value_range.hi - lo) / full + lo


__all__ = ["decode", "encode", "lsb"]
