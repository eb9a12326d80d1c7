"""How the envelope's geometric findings are keyed, worded and ordered, whether the numpy passes
or the compiled kernels found them: one `Violation` per (code, body name, wording), the earliest
kept, reported earliest first."""

from __future__ import annotations

import numpy as np

from armwarden.safety.bodies import CheckedBodies
from armwarden.safety.kernel.tables import KIND_SELF, KIND_WORKSPACE
from armwarden.safety.limits import Box
from armwarden.safety.violations import Code, Violation

#: findings keyed by (code, body name or "a|b" for a pair, wording)
Found = dict[tuple[str, str, str], Violation]

#: what the findings say, in the numpy passes and from the kernels' rows alike
LEAVES_WORKSPACE = "leaves the workspace box"
SELF_COLLISION = Code.SELF_COLLISION.value


def enters(zone: Box) -> str:
    return f"enters keep-out zone '{zone.name}'"


def report_order(bodies: CheckedBodies, kind: int, subject: str, zone: int) -> tuple[str, str, str]:
    """How `in_time_order` orders findings of one time, for the kernels: by code, body, then
    the wording after the body's name (for one body, its zones by name)."""
    if kind == KIND_SELF:
        return SELF_COLLISION, subject, ""
    if kind == KIND_WORKSPACE:
        return Code.WORKSPACE.value, subject, f" {LEAVES_WORKSPACE} near ("
    return Code.KEEP_OUT.value, subject, f" {enters(bodies.keep_out[zone])} near ("


def in_time_order(found: Found) -> list[Violation]:
    """The findings of geometry passes, earliest first, then by code, body and wording: one order
    however the passes met them."""
    if len(found) < 2:
        return list(found.values())
    return sorted(found.values(), key=lambda v: (time_of(v), v.code.value, v.body or "", v.detail))


def time_of(violation: Violation) -> float:
    """When a geometric finding happened (one without a time counts as at the start)."""
    return violation.time_s if violation.time_s is not None else 0.0


def self_collision(bodies: CheckedBodies, pair: int, distance: float, allowance: float, time: float) -> Violation:
    name_a, name_b = bodies.names[bodies.pairs[pair, 0]], bodies.names[bodies.pairs[pair, 1]]
    radii = bodies.pair_radii[pair]
    return Violation(
        Code.SELF_COLLISION,
        f"{name_a} and {name_b} come within {distance - radii:.3f} m of each other "
        f"(capsule surfaces, before the {allowance - radii:.3f} m sweep allowance)",
        time,
        f"{name_a}|{name_b}",
    )


def from_kernel_rows(bodies: CheckedBodies, hits: np.ndarray) -> Found:
    """The kernels' finding rows (`kernel.tables.HIT_COLUMNS`) as the numpy passes key and word them."""
    found: Found = {}
    for kind, index, zone, time, x, y, z, distance, allowance, _ in hits.tolist():
        if kind == KIND_SELF:
            violation = self_collision(bodies, int(index), distance, allowance, time)
            found[(SELF_COLLISION, violation.body or "", "")] = violation
            continue
        if kind == KIND_WORKSPACE:
            code, what = Code.WORKSPACE, LEAVES_WORKSPACE
        else:
            code, what = Code.KEEP_OUT, enters(bodies.keep_out[int(zone)])
        name = bodies.names[int(index)]
        found[(code.value, name, what)] = Violation(code, f"{name} {what} near ({x:.3f}, {y:.3f}, {z:.3f})", time, name)
    return found


def first_per_body(bodies: CheckedBodies, found: Found, mask: np.ndarray, t_s: np.ndarray, where: np.ndarray,
                   code: Code, what: str) -> None:
    """Adds to `found` one violation per body name: the first sample at which `mask` is set for
    any body of that name (a fitted link's capsules share it), at it the lowest-indexed body."""
    for k, body in zip(*np.nonzero(mask), strict=True):  # by sample, then body
        name = bodies.names[body]
        key = (code.value, name, what)
        if key in found:
            continue
        found[key] = Violation(code, f"{name} {what} near {_fmt(where[k, body])}", float(t_s[k]), name)


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in p) + ")"
