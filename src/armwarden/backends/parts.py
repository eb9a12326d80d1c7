"""The optional parts of a robot cell, and the cell record that holds them.

A backend always drives an arm (the `Backend` itself: lifecycle, joint state, execution and
stops). Everything else a cell may have is a part, in the manner of ros2_control's hardware
components: a gripper, cameras, a wrench sensor, a controller manager, collision thresholds,
error recovery, a graph description and a frame tree. Each part is a small base class with its
own deadlines; a backend builds the parts its cell has and puts them in a `Cell`. A part that is
absent is `None`: there are no capability flags to keep in step with the code, and the server
offers exactly the tools whose part is there (`Cell.capabilities`).

`Backend` calls a part only through its public methods, which keep the rules every part shares
(open backend, stop epoch, deadline; `armwarden.backends.hooks`, "Rules every backend follows").
A part's `stop_now`-style methods are called from any thread; everything else from the event loop.
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable
from dataclasses import dataclass, field

from armwarden.backends.values import CameraImage, ControllerInfo, GripperResult
from armwarden.core.state import GripperState, Transform, Wrench


class Gripper(abc.ABC):
    """Fingers that move to a width, grasp with a force, home, and stop from any thread."""

    #: fixed part of a move/grasp deadline [s]; the travel time at the requested speed is added
    timeout_s: float = 5.0
    #: the longest finger travel [m] a move or grasp may need (the gripper's full opening)
    travel_m: float = 0.1
    #: deadline for homing [s]
    home_timeout_s: float = 30.0

    @abc.abstractmethod
    def state(self) -> GripperState:
        """The published state, without waiting (`BackendError` if there is none fresh)."""

    @abc.abstractmethod
    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        """Move the fingers to `width_m` at `speed_mps`; refuse a width or speed out of range."""

    @abc.abstractmethod
    async def grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                    epsilon_outer_m: float) -> GripperResult:
        """Close on an object expected `width_m` wide (within the epsilons) with `force_n`."""

    @abc.abstractmethod
    async def home(self) -> GripperResult:
        """Calibrate/open the fingers fully."""

    @abc.abstractmethod
    def stop_now(self) -> None:
        """Any thread, never awaiting the event loop: the fingers stop where they are and the
        action in progress ends "stopped"."""


class Cameras(abc.ABC):
    """Named cameras that each take one picture on request."""

    #: deadline for a snapshot [s]
    timeout_s: float = 2.0
    #: added to the deadline while `set_up` says a one-time setup (an offscreen renderer's GL
    #: context and first frame) has not finished [s]
    setup_timeout_s: float = 0.0

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """The cameras, by the names the tools use."""

    def set_up(self) -> bool:
        """Whether the one-time setup `setup_timeout_s` allows for is done."""
        return True

    @abc.abstractmethod
    async def snapshot(self, camera: str) -> CameraImage:
        """One picture of `camera` (one of `names`)."""


class WrenchSensor(abc.ABC):
    """A force/torque estimate at the tool (a sensor, or the arm's own estimate)."""

    @abc.abstractmethod
    def latest(self) -> Wrench | None:
        """The published estimate without waiting; None: ask `read` under the read deadline."""

    async def read(self) -> Wrench | None:
        """The estimate, for a sensor that has none published yet (default: `latest`)."""
        return self.latest()


class PublishedWrench(WrenchSensor):
    """The estimate a backend's own thread publishes: `latest` reads it (and may raise
    `BackendError` when its source has died)."""

    def __init__(self, latest: Callable[[], Wrench | None]) -> None:
        self._latest = latest

    def latest(self) -> Wrench | None:
        return self._latest()


class Controllers(abc.ABC):
    """A controller manager: which controllers are loaded and active, and switching them."""

    #: deadline for listing or switching [s]
    timeout_s: float = 5.0

    @abc.abstractmethod
    async def list(self) -> list[ControllerInfo]: ...

    @abc.abstractmethod
    async def switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        """Activate and deactivate controllers in one switch; refuse one that would leave the arm
        without its trajectory controller while it moves."""


class CollisionThresholds(abc.ABC):
    """The arm's own contact reflex: the force and torque at which it stops itself."""

    #: deadline for a change [s]
    timeout_s: float = 2.0

    @abc.abstractmethod
    async def set(self, force_n: float, torque_nm: float) -> None: ...


class ErrorRecovery(abc.ABC):
    """Clearing the arm's own latched error (a reflex, a limit) after a human has looked."""

    #: deadline for a recovery [s]
    timeout_s: float = 10.0

    @abc.abstractmethod
    async def recover(self) -> None: ...


class Graph(abc.ABC):
    """A description of the middleware graph around the arm (nodes, topics, services, actions)."""

    #: deadline for a description [s]
    timeout_s: float = 2.0

    @abc.abstractmethod
    async def describe(self) -> dict[str, list[str]]: ...


class FrameTree(abc.ABC):
    """Frames beyond the robot model (a ROS tf tree): poses between any two of them."""

    #: deadline for a lookup [s]
    timeout_s: float = 0.5

    @abc.abstractmethod
    async def lookup(self, target_frame: str, source_frame: str) -> Transform:
        """The pose of `source_frame` in `target_frame`; `BackendError` if a frame is unknown,
        disconnected or stale."""


@dataclass(frozen=True)
class Capabilities:
    """What the cell offers, as the server and the Guard ask it: derived from `Cell`, never declared."""

    wrench: bool = False
    #: the arm's joint states carry measured joint torques (`JointState.efforts`)
    joint_torques: bool = False
    #: simulated seconds per wall-clock second (1: real time; a simulator may run faster)
    time_scale: float = 1.0
    #: the interval [s, wall clock] between the joint states the backend keeps while it runs
    #: steadily (None: not known, e.g. a topic's rate)
    joint_state_interval_s: float | None = None
    gripper: bool = False
    cameras: tuple[str, ...] = ()
    controllers: bool = False
    collision_thresholds: bool = False
    error_recovery: bool = False
    graph: bool = False
    #: frames of the robot model the backend reports poses of
    frames: tuple[str, ...] = field(default_factory=tuple)
    #: the backend looks up frames beyond the robot model (ROS tf): `lookup_transform`
    transforms: bool = False


@dataclass(frozen=True)
class Cell:
    """The optional parts of one robot cell (absent: None), the robot-model frames its backend
    reports poses of, and whether its joint states carry measured torques."""

    gripper: Gripper | None = None
    cameras: Cameras | None = None
    wrench: WrenchSensor | None = None
    controllers: Controllers | None = None
    collision_thresholds: CollisionThresholds | None = None
    error_recovery: ErrorRecovery | None = None
    graph: Graph | None = None
    transforms: FrameTree | None = None
    frames: tuple[str, ...] = ()
    #: every joint state the backend publishes carries measured joint torques (`JointState.efforts`)
    joint_torques: bool = False
    #: how many simulated seconds pass per wall-clock second: stamps are wall-clock (monotonic)
    #: while velocities are per simulated second, so whatever integrates states over their stamps
    #: (the contact observer) scales the intervals by this; 1 for hardware
    time_scale: float = 1.0
    #: the interval [s, wall clock] between the joint states the backend keeps (its servo period)
    #: while it runs steadily; None: not known. Times `time_scale`, it is how much of the arm's
    #: motion the contact observer integrates at once: over its cap, it can integrate none
    joint_state_interval_s: float | None = None

    @functools.cached_property
    def capabilities(self) -> Capabilities:
        """Read once: a cell's parts do not change once it is built."""
        return Capabilities(
            wrench=self.wrench is not None,
            joint_torques=self.joint_torques,
            time_scale=self.time_scale,
            joint_state_interval_s=self.joint_state_interval_s,
            gripper=self.gripper is not None,
            cameras=self.cameras.names if self.cameras is not None else (),
            controllers=self.controllers is not None,
            collision_thresholds=self.collision_thresholds is not None,
            error_recovery=self.error_recovery is not None,
            graph=self.graph is not None,
            frames=tuple(self.frames),
            transforms=self.transforms is not None,
        )
