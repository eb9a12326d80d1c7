"""Where the force monitor's contact reading comes from: a force/torque sensor, or the observer
over the joint torques the motors measure.

`choose_contact_source` decides once, from the policy and what the backend offers;
`JointTorqueContact` turns joint states into readings the monitor checks exactly like a sensor's
(present, finite, fresh, advancing stamp) plus the per-joint external torques it limits. A joint
state without measured torques, or with a non-finite value, is passed on as an unusable reading
and never fed to the observer: the monitor fails closed on it, and the observer's state stays
what the last good sample made it.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from armwarden.core.errors import BackendError
from armwarden.core.state import JointState, Wrench
from armwarden.safety.contact_observer import ContactObserver, ObserverSettings

if TYPE_CHECKING:
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

__all__ = ["ContactEstimate", "ContactSource", "JointTorqueContact", "choose_contact_source", "observer_for",
           "unintegrable_joint_states"]

ContactSource = Literal["sensor", "joint_torques"]

#: the TCP wrench estimate is checked against the force/torque limits only while the TCP Jacobian's
#: condition number is at most this: beyond it a small torque error is a large force error, and
#: the per-joint limits (always checked) are the reliable test
MAX_WRENCH_CONDITION = 100.0


@dataclass(frozen=True)
class ContactEstimate(Wrench):
    """A wrench at the TCP estimated from joint torques, with the per-joint external torques it
    came from [N·m] and the TCP Jacobian's condition number (see `TcpWrenchEstimate`)."""

    external_torques_nm: np.ndarray
    condition: float

    @property
    def wrench_trusted(self) -> bool:
        """Whether the TCP wrench is well enough conditioned to hold against the force limits."""
        return self.condition <= MAX_WRENCH_CONDITION


def choose_contact_source(source: str, has_sensor: bool, measures_torques: bool,
                          has_torque_limits: bool) -> ContactSource | None:
    """The source the monitor reads for a policy's `force.source`, or None when there is none.

    `auto`: the sensor where the backend has one, else the joint torques where it measures them
    and the policy limits them."""
    if source == "sensor":
        return "sensor" if has_sensor else None
    torques = measures_torques and has_torque_limits
    if source == "joint_torques":
        return "joint_torques" if torques else None
    if has_sensor:
        return "sensor"
    return "joint_torques" if torques else None


def observer_for(policy: Policy, robot_model: RobotModel) -> ContactObserver:
    """The observer for `policy`'s `force.joint_torques` section on the loaded robot model."""
    section = policy.force.joint_torques
    if section is None:
        raise ValueError("the policy has no force.joint_torques section")
    names = tuple(policy.robot.joint_names)
    settings = ObserverSettings(
        gain_per_s=section.observer_gain_per_s,
        coulomb_nm=section.per_joint("friction_coulomb_nm", names),
        viscous_nms=section.per_joint("friction_viscous_nms", names),
        payload_kg=section.payload_kg,
        payload_com_m=tuple(section.payload_com_m),  # type: ignore[arg-type]
        rotor_inertia_kgm2=section.per_joint("rotor_inertia_kgm2", names),
    )
    return ContactObserver(robot_model.model, robot_model.tcp_frame, robot_model.base_frame, settings)


#: the longest sample interval [s of the arm's time: stamps × time_scale] whose torques the observer
#: integrates from its two ends; a longer one (an event loop that stalled) is skipped, not trusted:
#: the torques may have risen and fallen inside it, and the trapezoid would read that as a contact
#: (28 N·m once in MuJoCo at the largest scaling, with nothing touching). Measured on the arm's
#: time, not the stamps': at speedup 10 a 5 ms stall is 50 ms of motion (read as 10.6 N·m)
MAX_INTEGRATED_INTERVAL_S = 0.02


def unintegrable_joint_states(interval_s: float | None, time_scale: float) -> str | None:
    """Why the observer can integrate none of a backend's joint states kept `interval_s` apart
    [s, wall clock] at `time_scale` (None: it can, or the interval is not known).

    Each interval is then `MAX_INTEGRATED_INTERVAL_S` or more of the arm's time: every one is
    skipped, and a free motion ends as a lost reading with the e-stop latched. Said before
    anything moves instead (e.g. a fake sped up 20 times samples 20 ms of motion a tick)."""
    if interval_s is None:
        return None
    arm_s = interval_s * time_scale
    if arm_s < MAX_INTEGRATED_INTERVAL_S:
        return None
    return (f"the backend keeps a joint state every {interval_s * 1e3:g} ms at speedup {time_scale:g}, "
            f"{arm_s * 1e3:g} ms of the arm's motion, and the joint-torque observer integrates less than "
            f"{MAX_INTEGRATED_INTERVAL_S * 1e3:g} ms at once (lower the speedup)")


#: joint speed [rad/s] under which a sample counts as an arm at rest (a skipped interval between two
#: of them misses nothing: no momentum changed)
REST_SPEED_RAD_S = 0.01


class JointTorqueContact:
    """Readings for the force monitor from joint states and one observer (one per execution).

    Each read takes every sample the backend published since the last one it integrated
    (`Backend.read_joint_states_since`: a servo loop's whole history, or the latest sample alone)
    and feeds them to the observer in order; the reading is the newest sample's estimate. The
    residual is a low-pass of the external torque (bandwidth `observer_gain_per_s`, 20 ms at the
    bundled 50 /s), so a poll between samples cannot step over a contact's rise.

    A sample interval longer than `MAX_INTEGRATED_INTERVAL_S` is skipped (`ContactObserver.rebase`):
    the estimate holds and the next interval starts from that sample. Skipped time that adds up
    to more than `max_unobserved_s` while the arm moved, without an integrated interval between, is a
    lost reading (fail closed): an observer that cannot integrate cannot see a contact. So is a
    sample without finite positions, velocities or torques, wherever it falls in a read. Both
    bounds are on the arm's time (the stamps' interval × `time_scale`): a simulator run faster
    than real time moves the arm that much further between two stamps."""

    def __init__(self, read_joint_states: Callable[[float | None], Awaitable[Sequence[JointState]]],
                 observer: ContactObserver, joint_names: Sequence[str], time_scale: float = 1.0,
                 max_unobserved_s: float = 0.1) -> None:
        if not (np.isfinite(time_scale) and time_scale > 0):
            raise ValueError(f"time_scale must be a positive number, got {time_scale}")
        self._read_joint_states = read_joint_states
        self.observer = observer
        self._joint_names = tuple(joint_names)
        #: simulated seconds per stamp second (a simulator run faster than real time; 1 on hardware)
        self._time_scale = float(time_scale)
        self._max_unobserved_s = float(max_unobserved_s)
        #: the arm's time (stamps × time_scale) skipped while it moved, since the last integrated interval [s]
        self.unobserved_s = 0.0
        #: samples integrated so far (each once)
        self.samples_integrated = 0
        self._moving = False
        self._last: ContactEstimate | None = None
        self._last_state: JointState | None = None

    async def read(self) -> Wrench | None:
        """The newest sample's estimate (BackendError when a state carries no torques at all)."""
        states = await self._read_joint_states(None if self._last_state is None else self._last_state.stamp)
        if not states:
            raise BackendError("the backend returned no joint state")
        for state in states:
            unusable = self._integrate(state)
            if unusable is not None:
                return unusable
        state = self._last_state
        if state is None:  # pragma: no cover - `_integrate` kept a sample or returned a reading
            raise BackendError("no joint state was integrated")
        if self._last is None or self._last.stamp != state.stamp:  # the newest sample's TCP wrench, once per read
            residual = self.observer.residual
            wrench = self.observer.tcp_wrench(np.asarray(state.positions, dtype=float), residual)
            self._last = ContactEstimate(wrench.force_n, wrench.torque_nm, float(state.stamp), residual,
                                         wrench.condition)
        return self._last

    def _integrate(self, state: JointState) -> ContactEstimate | None:
        """Feed one sample to the observer; an unusable reading when it cannot be (else None)."""
        if tuple(state.names) != self._joint_names:
            raise BackendError(f"the joint state names {list(state.names)}, not the policy's joints")
        if state.efforts is None:
            raise BackendError("the joint state carries no measured joint torques")
        q, v, tau = (np.asarray(x, dtype=float) for x in (state.positions, state.velocities, state.efforts))
        if not all(np.all(np.isfinite(x)) for x in (q, v, tau)) or not np.isfinite(state.stamp):
            return _unusable(state.stamp, len(self._joint_names))
        previous = self._last_state
        if previous is not None and state.stamp <= previous.stamp:  # the same sample again: nothing new
            return None
        # on the arm's time: what the observer integrates and what the arm moved through
        interval = (state.stamp - previous.stamp) * self._time_scale if previous is not None else 0.0
        if previous is not None and interval > MAX_INTEGRATED_INTERVAL_S:
            if self._moving or bool(np.any(np.abs(v) > REST_SPEED_RAD_S)):  # an arm at rest at both ends: nothing missed
                self.unobserved_s += interval
            if self.unobserved_s > self._max_unobserved_s:
                return _unusable(state.stamp, len(self._joint_names))
            self.observer.rebase(q, v, tau, state.stamp * self._time_scale)
        else:
            self.unobserved_s = 0.0
            self.observer.update(q, v, tau, state.stamp * self._time_scale)
            self.samples_integrated += 1
        self._moving = bool(np.any(np.abs(v) > REST_SPEED_RAD_S))
        self._last_state = state
        return None


def _unusable(stamp: float, joints: int) -> ContactEstimate:
    """A reading the monitor refuses as not finite (`wrench_invalid`)."""
    nan = np.full(3, np.nan)
    return ContactEstimate(nan, nan, float(stamp), np.full(joints, np.nan), np.inf)
