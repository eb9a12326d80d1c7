"""The force monitor: watches the external wrench while the arm moves, and fails closed.

Why: the envelope keeps planned motion away from what the policy knows about, but not from
what it does not (a person, a misplaced box). The contact force is the last line of defence, so
the monitor treats "cannot tell" exactly like "too much": a wrench that is missing, slow to
read, frozen (its stamp stops advancing) or not finite ends the motion just as a force over the
limit does (docs/architecture.md, "Where each limit is enforced").

How: `baseline()` reads the wrench once before the motion starts. `run()` then polls it at
`monitor_rate_hz`, each read bounded by `wrench_timeout_s`, until it finds a violation (which
it hands to `on_violation`, shielded from cancellation so the stop and the latch complete, and
returns) or until the Guard cancels it because the motion ended; `check_once()` then takes one
last sample, so a crossing inside the last polling period is not missed. A sample older than
`wrench_timeout_s` (stamps are on the monotonic clock) counts as no sample.

If the arm was already pressing harder than the limit when the motion started (e.g. resting on a
surface), the limit becomes "no more than 1 N (0.2 N·m) above that baseline", so the arm can move
away but not push harder. That allowance does not stack: the Guard carries the ceiling of the
first such motion over to the next ones (`carried_ceiling`) until a baseline is back under the
limit, so a series of small motions cannot ratchet the force up 1 N at a time. A baseline more
than `BASELINE_CAP_FACTOR` times the limit is not moved from at all (`baseline_excessive`).

Without a force/torque sensor the readings are `ContactEstimate`s from the joint-torque observer
(`contact_source`): each also carries the external torque per joint, which is held against the
policy's per-joint limits with the same baseline rule (allowance `JOINT_TORQUE_RISE_ALLOWANCE_NM`),
and its TCP wrench is held against the force and torque limits only while it is well conditioned.

One monitor per execution. The monitor never stops the robot itself: `on_violation` (the Guard)
does. The clock is injected so tests never sleep for timing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import asdict, dataclass
from typing import Any, Literal

import anyio
import numpy as np

from armwarden.core.errors import ConfigurationError
from armwarden.core.state import Wrench
from armwarden.safety.contact_source import ContactEstimate

__all__ = [
    "FORCE_RISE_ALLOWANCE_N",
    "JOINT_TORQUE_RISE_ALLOWANCE_NM",
    "TORQUE_RISE_ALLOWANCE_NM",
    "ForceLimits",
    "ForceMonitor",
    "ForceViolation",
    "ViolationKind",
]

#: with a baseline above the force limit, the largest allowed rise above the baseline [N]
FORCE_RISE_ALLOWANCE_N = 1.0
#: with a baseline above the torque limit, the largest allowed rise above the baseline [N·m]
TORQUE_RISE_ALLOWANCE_NM = 0.2
#: with a joint's baseline external torque above its limit, the largest allowed rise [N·m]
JOINT_TORQUE_RISE_ALLOWANCE_NM = 0.5
#: a baseline above this multiple of a limit is not moved from (a human must relieve the contact)
BASELINE_CAP_FACTOR = 2.0

ViolationKind = Literal[
    "force_limit", "torque_limit", "joint_torque_limit",
    "wrench_missing", "wrench_timeout", "wrench_frozen", "wrench_stale", "wrench_invalid",
]


@dataclass(frozen=True)
class ForceLimits:
    """What the monitor enforces, in SI units; validated at construction."""

    max_force_n: float
    max_torque_nm: float
    monitor_rate_hz: float = 200.0
    wrench_timeout_s: float = 0.1
    #: whether execution needs a wrench at all (the Guard's decision; the monitor always fails closed)
    require_wrench: bool = True
    #: per-joint limits on the external torque a joint-torque estimate reports [N·m] (None: no such limits)
    max_external_torque_nm: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        for name in ("max_force_n", "max_torque_nm", "monitor_rate_hz", "wrench_timeout_s"):
            _require_positive(name, getattr(self, name))
        for index, value in enumerate(self.max_external_torque_nm or ()):
            _require_positive(f"max_external_torque_nm[{index}]", value)

    @classmethod
    def from_policy(cls, policy, source: str = "sensor") -> ForceLimits:
        """The policy's limits for contact read from `source` ("sensor" or "joint_torques": a
        force estimated from joint torques is held against `joint_torques.max_tcp_force_n`)."""
        force = policy.force
        return cls(
            max_force_n=force.estimated_force_limit_n if source == "joint_torques" else force.max_contact_force_n,
            max_torque_nm=force.max_contact_torque_nm,
            monitor_rate_hz=force.monitor_rate_hz,
            wrench_timeout_s=force.wrench_timeout_s,
            require_wrench=force.require_wrench,
            max_external_torque_nm=None if force.joint_torques is None else force.joint_torques.per_joint(
                "max_external_torque_nm", tuple(policy.robot.joint_names)),
        )

    @property
    def period_s(self) -> float:
        return 1.0 / self.monitor_rate_hz


def _require_positive(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigurationError(f"force limit {name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True)
class ForceViolation:
    """Why the motion must stop; forces are None when no usable sample was read. A joint-torque
    estimate also gives the external torque per joint [N·m]."""

    kind: ViolationKind
    detail: str
    force_n: float | None
    torque_nm: float | None
    at_mono: float
    external_torques_nm: tuple[float, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the audit log and the e-stop event (the joint torques only where estimated)."""
        data = asdict(self)
        if self.external_torques_nm is None:
            del data["external_torques_nm"]
        else:
            data["external_torques_nm"] = list(self.external_torques_nm)
        return data


def _finite_vector(value: object) -> np.ndarray | None:
    """`value` as a finite 3-vector, or None."""
    try:
        vector = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return None
    return vector if vector.shape == (3,) and bool(np.all(np.isfinite(vector))) else None


class ForceMonitor:
    """Polls the wrench during one execution; see the module docstring."""

    def __init__(
        self,
        limits: ForceLimits,
        read_wrench: Callable[[], Awaitable[Wrench | None]],
        clock: Callable[[], float] = time.monotonic,
        carried_ceiling: tuple[float | None, float | None] = (None, None),
        carried_joint_ceiling: tuple[float | None, ...] | None = None,
    ) -> None:
        self.limits = limits
        self.carried_ceiling = carried_ceiling
        self.carried_joint_ceiling = carried_joint_ceiling
        self._read_wrench = read_wrench
        self._clock = clock
        self.baseline_wrench: Wrench | None = None
        #: largest force / torque norm seen in a valid sample (baseline included), for the report
        self.max_observed_force_n = 0.0
        self.max_observed_torque_nm = 0.0
        #: largest |external torque| per joint seen in a valid joint-torque estimate (None: not one yet)
        self.max_observed_external_torques_nm: np.ndarray | None = None
        self.samples = 0
        self._last_stamp: float | None = None
        self._stamp_advanced_mono = 0.0

    # ------------------------------------------------------------------ thresholds
    @property
    def force_threshold_n(self) -> float:
        """The force norm [N] above which the motion stops (the limit, or baseline + allowance)."""
        return self._threshold(self.limits.max_force_n, self._baseline_norms()[0], FORCE_RISE_ALLOWANCE_N,
                               self.carried_ceiling[0])

    @property
    def torque_threshold_nm(self) -> float:
        """The torque norm [N·m] above which the motion stops (the limit, or baseline + allowance)."""
        return self._threshold(self.limits.max_torque_nm, self._baseline_norms()[1], TORQUE_RISE_ALLOWANCE_NM,
                               self.carried_ceiling[1])

    @property
    def joint_torque_thresholds_nm(self) -> tuple[float, ...] | None:
        """Per joint, the external torque [N·m] above which the motion stops (the limit, or the
        baseline + allowance where the baseline is above it); None without per-joint limits."""
        limits = self.limits.max_external_torque_nm
        if limits is None:
            return None
        baseline = self._baseline_joint_torques()
        carried = self.carried_joint_ceiling or (None,) * len(limits)
        return tuple(self._threshold(limit, None if baseline is None else float(baseline[j]),
                                     JOINT_TORQUE_RISE_ALLOWANCE_NM, carried[j] if j < len(carried) else None)
                     for j, limit in enumerate(limits))

    @property
    def joint_contact_ceiling(self) -> tuple[float | None, ...] | None:
        """The per-joint thresholds to carry into the next execution (as `contact_ceiling`)."""
        limits, thresholds = self.limits.max_external_torque_nm, self.joint_torque_thresholds_nm
        baseline = self._baseline_joint_torques()
        if limits is None or thresholds is None or baseline is None:
            return None
        return tuple(thresholds[j] if baseline[j] > limit else None for j, limit in enumerate(limits))

    def _baseline_joint_torques(self) -> np.ndarray | None:
        """|external torque| per joint at the baseline (None: not a joint-torque estimate)."""
        baseline = self.baseline_wrench
        if not isinstance(baseline, ContactEstimate):
            return None
        return np.abs(np.asarray(baseline.external_torques_nm, dtype=float))

    @staticmethod
    def _threshold(limit: float, baseline: float | None, allowance: float, carried: float | None) -> float:
        if baseline is None or baseline <= limit:
            return limit
        return baseline + allowance if carried is None else min(baseline + allowance, carried)

    @property
    def contact_ceiling(self) -> tuple[float | None, float | None]:
        """The thresholds to carry into the next execution: set per axis while its baseline is above
        the limit, None once it is back under (the contact was relieved)."""
        force, torque = self._baseline_norms()
        return (self.force_threshold_n if force is not None and force > self.limits.max_force_n else None,
                self.torque_threshold_nm if torque is not None and torque > self.limits.max_torque_nm else None)

    @property
    def baseline_excessive(self) -> bool:
        """The baseline is more than `BASELINE_CAP_FACTOR` times a limit: do not move from here."""
        force, torque = self._baseline_norms()
        joints, joint_limits = self._baseline_joint_torques(), self.limits.max_external_torque_nm
        return (force is not None and force > BASELINE_CAP_FACTOR * self.limits.max_force_n) or (
            torque is not None and torque > BASELINE_CAP_FACTOR * self.limits.max_torque_nm) or (
            joints is not None and joint_limits is not None
            and bool(np.any(joints > BASELINE_CAP_FACTOR * np.asarray(joint_limits))))

    def _baseline_norms(self) -> tuple[float | None, float | None]:
        """The baseline's force and torque norms (None: no baseline, or an estimate whose TCP
        wrench is too poorly conditioned to be held against the limits)."""
        baseline = self.baseline_wrench
        if baseline is None or (isinstance(baseline, ContactEstimate) and not baseline.wrench_trusted):
            return None, None
        return baseline.force_norm_n, baseline.torque_norm_nm

    # ------------------------------------------------------------------ reading
    async def baseline(self) -> Wrench | ForceViolation:
        """Read the wrench before the motion; the violation (missing, slow, unreadable, not finite,
        stale) if it cannot be used."""
        self.baseline_wrench = None
        sample = await self._read_sample()
        if isinstance(sample, ForceViolation):
            return sample
        self.baseline_wrench = sample
        return sample

    async def check_once(self) -> ForceViolation | None:
        """One sample checked like every sample of `run` (e.g. right after the motion ended)."""
        sample = await self._read_sample()
        return sample if isinstance(sample, ForceViolation) else self._check_limits(sample)

    async def run(self, on_violation: Callable[[ForceViolation], Awaitable[None]] | None = None) -> ForceViolation:
        """Poll until a violation (returned after `on_violation` has run) or until cancelled."""
        while True:
            violation = await self.check_once()
            if violation is not None:
                if on_violation is not None:
                    with anyio.CancelScope(shield=True):  # the stop and the latch must complete
                        await on_violation(violation)
                return violation
            await anyio.sleep(self.limits.period_s)

    async def _read_sample(self) -> Wrench | ForceViolation:
        """One bounded read, checked for presence, finiteness and a stamp that keeps advancing."""
        timeout_s = self.limits.wrench_timeout_s
        try:
            with anyio.fail_after(timeout_s):
                wrench = await self._read_wrench()
        except TimeoutError:
            return self._violation("wrench_timeout", f"wrench read took longer than {timeout_s:g} s")
        except Exception as exc:  # a failing sensor is a missing sensor; cancellation still propagates
            reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
            return self._violation("wrench_missing", f"wrench read failed ({reason})")
        now = self._clock()
        if wrench is None:
            return self._violation("wrench_missing", "no wrench estimate available")
        force = _finite_vector(getattr(wrench, "force", None))
        torque = _finite_vector(getattr(wrench, "torque", None))
        stamp = getattr(wrench, "stamp", None)
        if force is None or torque is None or not isinstance(stamp, (int, float)) or not math.isfinite(stamp):
            return self._violation("wrench_invalid", "wrench has non-finite or malformed force, torque or stamp")
        if isinstance(wrench, ContactEstimate):
            joints = np.abs(np.asarray(wrench.external_torques_nm, dtype=float)).reshape(-1)
            expected = self.limits.max_external_torque_nm
            if not np.all(np.isfinite(joints)) or (expected is not None and joints.shape != (len(expected),)):
                return self._violation("wrench_invalid", "the joint-torque estimate has non-finite or missing joints")
            peak = self.max_observed_external_torques_nm
            self.max_observed_external_torques_nm = joints if peak is None else np.maximum(peak, joints)
        force_n, torque_nm = float(np.linalg.norm(force)), float(np.linalg.norm(torque))
        self.samples += 1
        if not isinstance(wrench, ContactEstimate) or wrench.wrench_trusted:
            self.max_observed_force_n = max(self.max_observed_force_n, force_n)
            self.max_observed_torque_nm = max(self.max_observed_torque_nm, torque_nm)
        if self._last_stamp is None or stamp > self._last_stamp:
            self._last_stamp, self._stamp_advanced_mono = float(stamp), now
        elif now - self._stamp_advanced_mono > timeout_s:
            return self._violation(
                "wrench_frozen",
                f"wrench stamp has not advanced for {now - self._stamp_advanced_mono:.3f} s "
                f"(more than {timeout_s:g} s)",
                force_n,
                torque_nm,
            )
        if now - stamp > timeout_s:  # advancing, but late (or from another clock): not a current reading
            return self._violation("wrench_stale", f"wrench sample is {now - stamp:.3f} s old (more than {timeout_s:g} s)",
                                   force_n, torque_nm)
        return wrench

    def _check_limits(self, wrench: Wrench) -> ForceViolation | None:
        if isinstance(wrench, ContactEstimate):
            found = self._check_joint_torques(wrench)
            if found is not None or not wrench.wrench_trusted:
                return found
        force_n, torque_nm = wrench.force_norm_n, wrench.torque_norm_nm
        force_max, torque_max = self.force_threshold_n, self.torque_threshold_nm
        how = " estimated from the motors' torques" if isinstance(wrench, ContactEstimate) else ""
        if force_n > force_max:
            return self._violation(
                "force_limit", f"contact force{how} {force_n:.2f} N exceeds {self._describe(force_max, 'force')}",
                force_n, torque_nm,
            )
        if torque_nm > torque_max:
            return self._violation(
                "torque_limit", f"contact torque{how} {torque_nm:.3f} N·m exceeds {self._describe(torque_max, 'torque')}",
                force_n, torque_nm,
            )
        return None

    def _check_joint_torques(self, estimate: ContactEstimate) -> ForceViolation | None:
        thresholds = self.joint_torque_thresholds_nm
        if thresholds is None:
            return None
        torques = np.asarray(estimate.external_torques_nm, dtype=float)
        over = [j for j, threshold in enumerate(thresholds) if abs(torques[j]) > threshold]
        if not over:
            return None
        j = max(over, key=lambda k: abs(torques[k]) / thresholds[k])
        limit = self.limits.max_external_torque_nm[j]  # type: ignore[index]  # thresholds imply limits
        bound = (f"the limit of {limit:g} N·m" if thresholds[j] == limit else
                 f"{thresholds[j]:.2f} N·m (baseline above the {limit:g} N·m limit, plus "
                 f"{JOINT_TORQUE_RISE_ALLOWANCE_NM:g} N·m)")
        return self._violation(
            "joint_torque_limit",
            f"external torque at joint {j + 1} estimated from the motors' torques is {abs(torques[j]):.2f} N·m, "
            f"over {bound}", estimate.force_norm_n if estimate.wrench_trusted else None,
            estimate.torque_norm_nm if estimate.wrench_trusted else None,
            tuple(float(t) for t in torques))

    def _describe(self, threshold: float, which: str) -> str:
        if which == "force":
            limit, unit, allowance = self.limits.max_force_n, "N", FORCE_RISE_ALLOWANCE_N
        else:
            limit, unit, allowance = self.limits.max_torque_nm, "N·m", TORQUE_RISE_ALLOWANCE_NM
        if threshold == limit:
            return f"the limit of {limit:g} {unit}"
        return f"{threshold:.2f} {unit} (baseline above the {limit:g} {unit} limit, plus {allowance:g} {unit})"

    def _violation(
        self, kind: ViolationKind, detail: str, force_n: float | None = None, torque_nm: float | None = None,
        external_torques_nm: tuple[float, ...] | None = None,
    ) -> ForceViolation:
        return ForceViolation(kind, detail, force_n, torque_nm, self._clock(), external_torques_nm)
