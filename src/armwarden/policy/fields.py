"""Building blocks of the policy models: frozen containers, strict field types, rule plumbing.

Cross-field rules are small functions yielding `(relative path, message)` violations; `enforce`
raises them all at once so `messages.validation_errors` can report each at its own YAML path.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, ConfigDict, Field

_K = TypeVar("_K")
_V = TypeVar("_V")


class FrozenMap(Mapping[_K, _V]):
    """A read-only mapping that keeps insertion order, hashes, compares like a dict and pickles.

    `types.MappingProxyType` would do, except that it cannot be copied or pickled, and callers
    (tests, `model_copy(deep=True)`) legitimately do both.
    """

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[_K, _V] | Iterable[tuple[_K, _V]] = ()) -> None:
        self._data: dict[_K, _V] = dict(data)

    def __getitem__(self, key: _K) -> _V:
        return self._data[key]

    def __iter__(self) -> Iterator[_K]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __hash__(self) -> int:
        return hash(tuple(self._data.items()))

    def __repr__(self) -> str:
        return f"FrozenMap({self._data!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (FrozenMap, (self._data,))


def serialize_map(value: Mapping[Any, Any], handler: Callable[[Any], Any]) -> Any:
    return handler(dict(value))


def freeze_map(value: Mapping[Any, Any]) -> FrozenMap[Any, Any]:
    return FrozenMap(value)


def unique_names(values: tuple[str, ...]) -> tuple[str, ...]:
    """Reject repeated names: a repeat is almost always a typo for a name that is now missing."""
    seen: set[str] = set()
    repeated = [v for v in values if v in seen or seen.add(v)]  # type: ignore[func-returns-value]
    if repeated:
        raise ValueError(f"names must be unique; repeated: {sorted(set(repeated))}")
    return values


def not_empty(values: tuple[str, ...]) -> tuple[str, ...]:
    """Checked after the items (pydantic's `min_length` would also fire when an item is invalid)."""
    if not values:
        raise ValueError("must list at least one name")
    return values


def finite(**limits: Any) -> Any:
    """A strict, finite float field constraint (ints are accepted and widened; bools are not)."""
    return Field(strict=True, allow_inf_nan=False, **limits)


#: A finite float (no NaN/Inf, no bool, no numeric string).
FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]
#: A name: non-empty, no whitespace (joints, frames, links, cameras, controllers, zones).
Name = Annotated[str, Field(strict=True, min_length=1, max_length=128, pattern=r"^\S+$")]
UniqueNames = Annotated[tuple[Name, ...], AfterValidator(unique_names)]
#: Largest |coordinate| [m] of a workspace or keep-out corner. No arm ArmWarden drives reaches
#: this far from its base; a larger number is almost always centimetres or millimetres written
#: where metres belong, which would silently move a box out of the arm's way.
MAX_COORDINATE_M = 5.0
#: A coordinate [m] in the robot base frame, within ±MAX_COORDINATE_M.
Coordinate = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M)]
#: [x, y, z] in metres, in the robot base frame.
Vector3 = tuple[Coordinate, Coordinate, Coordinate]
StrictBool = Annotated[bool, Field(strict=True)]
#: The largest calls-per-minute a rate limit may name: far beyond any client (one call every 6 µs),
#: and small enough to be a float exactly (a bigger int overflowed the limiter at start-up)
MAX_RATE_PER_MINUTE = 10_000_000
Rate = Annotated[int, Field(strict=True, ge=1, le=MAX_RATE_PER_MINUTE)]

MODEL_CONFIG = ConfigDict(extra="forbid", frozen=True)

# ====================================================================== cross-field rule plumbing

Violation = tuple[tuple[str | int, ...], str]
"""A rule violation: the path of the offending value relative to the model, and a message."""


class RuleViolations(ValueError):
    """Raised by a model's rule check; carries every violation with its relative path.

    Pydantic keeps the raised exception in the error's context, so `validation_errors`
    can turn each violation into its own `(yaml_path, message)` pair with an exact path.
    """

    def __init__(self, violations: Sequence[Violation]) -> None:
        self.violations = list(violations)
        super().__init__("; ".join(message for _, message in self.violations))


def enforce(rules: Iterable[Iterable[Violation]]) -> None:
    """Run every rule and raise once with all their violations (so all are reported together)."""
    violations = [violation for rule in rules for violation in rule]
    if violations:
        raise RuleViolations(violations)


def check_min_below_max(lo: Sequence[float], hi: Sequence[float]) -> Iterator[Violation]:
    """An axis-aligned box needs min < max on every axis; an empty or flat box is a typo."""
    bad = [f"{axis}: {a:g} >= {b:g}" for axis, a, b in zip("xyz", lo, hi, strict=True) if not a < b]
    if bad:
        yield ("min",), f"min must be less than max on every axis ({', '.join(bad)})"


def boxes_overlap(lo_a: Sequence[float], hi_a: Sequence[float], lo_b: Sequence[float], hi_b: Sequence[float]) -> bool:
    """Whether two axis-aligned boxes share interior volume (touching faces do not count)."""
    return all(a0 < b1 and b0 < a1 for a0, a1, b0, b1 in zip(lo_a, hi_a, lo_b, hi_b, strict=True))
