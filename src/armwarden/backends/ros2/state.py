"""Thread-safe caches of what the cell publishes, stamped with when it arrived.

Subscription callbacks (the executor thread) `accept` messages; the event loop and any stopping
thread read the latest sample without waiting. Freshness is judged by *receipt* time on the
monotonic clock, never by the sender's header stamp (another clock, possibly simulated); the
header stamp is only checked to move forward: a message whose stamp goes backwards, or repeats
(a frozen driver), is not a new sample, so the cache ages and the reader refuses it. Durations on
the sender's clock are meaningful, though: "measured at least this long after that sample" is how
a stop knows a sample shows the arm after the stop, even when our executor reads a backlog late.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import anyio
import numpy as np

from armwarden.backends.ros2.dds import DdsSettings
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState, Wrench

Clock = Callable[[], float]


def header_seconds(stamp) -> float:
    """A builtin_interfaces/Time as seconds."""
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _frozen(values: np.ndarray) -> np.ndarray:
    values.setflags(write=False)
    return values


@dataclass(frozen=True)
class _Sample:
    state: JointState
    header_s: float


def nothing_heard(network: DdsSettings | None) -> str:
    """The tail of a "nothing arrived" message: the domain and range in use, and how to agree."""
    return "" if network is None else f" (this node: {network.describe()}; {network.how_to_agree()})"


def _efforts(msg, index: dict[str, int], ros_names: Sequence[str]) -> np.ndarray:
    """The measured joint torques of `msg` for `ros_names`, by name: NaN for a joint without an
    entry (an empty or short `effort`), a NaN passed on as it is. Never zero, never an older
    value: the force monitor fails closed on NaN, and a made-up torque would hide a contact."""
    effort = msg.effort
    return np.array([float(effort[i]) if (i := index[name]) < len(effort) else np.nan for name in ros_names],
                    dtype=float)


class JointStateCache:
    """The latest complete joint state, mapped by name to the policy's joint order; with
    `efforts`, the measured joint torques of the same message too (see `_efforts`)."""

    def __init__(self, topic: str, joint_names: Sequence[str], ros_names: Sequence[str], max_age_s: float,
                 clock: Clock = time.monotonic, *, network: DdsSettings | None = None, efforts: bool = False) -> None:
        self.topic = topic
        self.efforts = efforts
        self.network = network  # named when nothing came: most often the other side is on another domain
        self.joint_names = tuple(joint_names)
        self.ros_names = tuple(ros_names)
        self.max_age_s = max_age_s
        self._clock = clock
        self._lock = threading.Lock()
        self._sample: _Sample | None = None
        #: messages not taken, and why the last one was not (for the stale message)
        self.dropped = 0
        self.last_drop: str = ""

    def accept(self, msg) -> None:
        """Executor thread: take `msg` (sensor_msgs/JointState) if it is complete and newer."""
        now = self._clock()
        index = {name: i for i, name in enumerate(msg.name)}
        missing = [name for name in self.ros_names if name not in index]
        header_s = header_seconds(msg.header.stamp)
        with self._lock:
            previous = self._sample
            if missing:  # e.g. another publisher's message (the fingers) on the same topic
                self._drop(f"a message lacked {', '.join(missing)}")
                return
            try:
                positions = np.array([msg.position[index[name]] for name in self.ros_names], dtype=float)
                velocities = (np.array([msg.velocity[index[name]] for name in self.ros_names], dtype=float)
                              if len(msg.velocity) == len(msg.name) else None)
            except IndexError:
                self._drop("a message had fewer positions than names")
                return
            if not np.all(np.isfinite(positions)) or (velocities is not None and not np.all(np.isfinite(velocities))):
                self._drop("a message had non-finite positions or velocities")
                return
            if previous is not None and header_s <= previous.header_s:
                self._drop(f"the header stamp went backwards or repeated ({header_s:.6f} s after {previous.header_s:.6f} s)")
                return
            if velocities is None:  # no velocities published: difference the positions (zero for the first)
                dt = now - previous.state.stamp if previous is not None else 0.0
                velocities = (positions - previous.state.positions) / dt if previous is not None and dt > 0 else np.zeros_like(positions)
            stamp = max(now, previous.state.stamp) if previous is not None else now
            efforts = _frozen(_efforts(msg, index, self.ros_names)) if self.efforts else None
            state = JointState(self.joint_names, _frozen(positions), _frozen(velocities), stamp, efforts)
            self._sample = _Sample(state, header_s)

    def _drop(self, why: str) -> None:
        self.dropped += 1
        self.last_drop = why

    def latest(self) -> JointState | None:
        with self._lock:
            return None if self._sample is None else self._sample.state

    def latest_header_s(self) -> float | None:
        """The header stamp [s, the sender's clock] of the latest sample: when it was measured."""
        with self._lock:
            return None if self._sample is None else self._sample.header_s

    def age_s(self) -> float | None:
        return self.latest_with_age()[1]

    def latest_with_age(self) -> tuple[JointState | None, float | None]:
        """The latest sample and its age [s] (since it arrived), read together."""
        state = self.latest()
        return state, None if state is None else self._clock() - state.stamp

    def fresh(self) -> JointState:
        """The latest sample, or `BackendError` naming how old it is (or that none came)."""
        return self.fresh_measured()[0]

    def fresh_measured(self) -> tuple[JointState, float]:
        """`fresh`, with the sample's header stamp [s, the sender's clock]."""
        with self._lock:
            sample = self._sample
        if sample is None:
            why = f"; {self.dropped} message(s) not used: {self.last_drop}" if self.dropped else ""
            raise BackendError(f"no joint state received on {self.topic} yet{why}{nothing_heard(self.network)}")
        age = self._clock() - sample.state.stamp
        if age > self.max_age_s:
            why = f"; {self.dropped} message(s) not used, the last because {self.last_drop}" if self.dropped else ""
            raise BackendError(f"joint states on {self.topic} are {age:.2f} s old (limit {self.max_age_s:g} s){why}")
        return sample.state, sample.header_s


class WrenchCache:
    """The latest wrench; its stamp is the receipt time of the last *new* header stamp, so a
    frozen header stamp makes it age like a silent topic."""

    def __init__(self, topic: str, max_age_s: float, frame_id: str | None, clock: Clock = time.monotonic, *,
                 network: DdsSettings | None = None) -> None:
        self.topic = topic
        self.network = network
        self.max_age_s = max_age_s
        self.frame_id = frame_id
        self._clock = clock
        self._lock = threading.Lock()
        self._wrench: Wrench | None = None
        self._header_s: float | None = None
        self.last_drop = ""

    def accept(self, msg) -> None:
        """Executor thread: take `msg` (geometry_msgs/WrenchStamped) if its stamp is new."""
        now = self._clock()
        header_s = header_seconds(msg.header.stamp)
        f, t = msg.wrench.force, msg.wrench.torque
        force, torque = np.array([f.x, f.y, f.z], dtype=float), np.array([t.x, t.y, t.z], dtype=float)
        with self._lock:
            if self.frame_id is not None and msg.header.frame_id != self.frame_id:
                self.last_drop = f"a message was in frame {msg.header.frame_id!r}, not {self.frame_id!r}"
                return
            if self._header_s is not None and header_s <= self._header_s:
                self.last_drop = "its header stamp stopped advancing"
                return
            self._header_s = header_s
            self._wrench = Wrench(_frozen(force), _frozen(torque), now)

    @property
    def received(self) -> bool:
        """Whether a wrench has arrived yet."""
        with self._lock:
            return self._wrench is not None

    def fresh(self) -> Wrench:
        """The latest wrench, or `BackendError` naming its age (or that none came)."""
        with self._lock:
            wrench, why = self._wrench, self.last_drop
        if wrench is None:
            raise BackendError(f"no wrench received on {self.topic} yet{nothing_heard(self.network)}")
        age = self._clock() - wrench.stamp
        if age > self.max_age_s:
            cause = f" ({why})" if why else ""
            raise BackendError(f"the wrench on {self.topic} is {age:.2f} s old (limit {self.max_age_s:g} s){cause}")
        return wrench


#: how often open looks again for the first samples [s]
FIRST_SAMPLE_POLL_S = 0.01


async def wait_for_first_samples(joint_states: JointStateCache, fingers: JointStateCache | None,
                                 wrench: WrenchCache | None, timeout_s: float, network: DdsSettings | None,
                                 require_spinning: Callable[[], None]) -> None:
    """Open ends once the arm's joint states (and the fingers' and the wrench, when configured)
    have arrived: reads right after open must not find a stream not yet discovered.
    `require_spinning` raises when the executor died (nothing would arrive then)."""
    deadline = time.monotonic() + timeout_s
    for cache in (joint_states, fingers):
        while cache is not None and cache.latest() is None:
            require_spinning()
            if time.monotonic() > deadline:
                why = f" ({cache.last_drop})" if cache.dropped else ""
                raise BackendError(f"no joint state naming {', '.join(cache.ros_names)} arrived on "
                                   f"{cache.topic} within {timeout_s:g} s{why}{nothing_heard(network)}")
            await anyio.sleep(FIRST_SAMPLE_POLL_S)
    while wrench is not None and not wrench.received:
        if time.monotonic() > deadline:
            raise BackendError(f"no wrench arrived on {wrench.topic} within {timeout_s:g} s{nothing_heard(network)}")
        await anyio.sleep(FIRST_SAMPLE_POLL_S)


__all__ = ["JointStateCache", "WrenchCache", "header_seconds", "wait_for_first_samples"]
