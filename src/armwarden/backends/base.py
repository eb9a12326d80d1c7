"""The backend contract: what a robot backend (fake, MuJoCo, ROS 2, CAN) implements.

The base class `Backend` owns what is common — the open/closed lifecycle, deadlines, logging,
trajectory checks and the stop semantics — and calls small `_hooks` that each backend implements
(template methods, as python-can's `BusABC.recv` calls `_recv_internal`) for the arm, and the
parts of its cell (`armwarden.backends.parts`, called from `part_calls`) for the rest. Backends only talk to
hardware or simulation: they never decide whether a motion is allowed; the Guard is the only
caller. What a backend writes and the rules it keeps are the docstring of
`armwarden.backends.hooks` (next to the hooks themselves); this class enforces what it can of them
for every backend, and `tests/backends/contract.py` (`BackendContract`) checks them all.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Awaitable, Callable, Sequence
from typing import TypeVar

import anyio
import numpy as np

from armwarden.backends.arm_state import ArmEvent, ArmState, ArmStateReporting
from armwarden.backends.death import DeathInjection
from armwarden.backends.faults import FaultReporting
from armwarden.backends.hooks import BackendHooks
from armwarden.backends.part_calls import PartCalls
from armwarden.backends.parts import Capabilities, Cell
from armwarden.backends.values import PREEMPTED, ExecutionResult, ProgressCallback
from armwarden.backends.workers import WorkerSupervision
from armwarden.core.errors import BackendError, BackendTimeout, StoppedBeforeStart
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory

logger = logging.getLogger(__name__)

T = TypeVar("T")


class Backend(ArmStateReporting, FaultReporting, WorkerSupervision, DeathInjection, PartCalls, BackendHooks):
    """Base class: lifecycle, deadlines, checks, the arm state and logging; subclasses implement the `_hooks`."""

    def __init_subclass__(cls, **kwargs: object) -> None:
        """A backend says what its cell has by its parts; a `capabilities` of its own (the flags of
        before the cell) would offer tools whose calls then fail, so a class defining one is refused."""
        super().__init_subclass__(**kwargs)
        if "capabilities" in vars(cls):
            raise TypeError(f"{cls.__qualname__} defines `capabilities`: build its parts into `self.cell` "
                            "instead (docs/add-a-backend.md)")

    def __init__(self, joint_names: Sequence[str], *, start_tolerance_rad: float) -> None:
        if not (isinstance(start_tolerance_rad, (int, float)) and math.isfinite(start_tolerance_rad)
                and start_tolerance_rad > 0):
            raise ValueError(f"start_tolerance_rad must be a positive angle [rad], got {start_tolerance_rad!r}")
        super().__init__()
        self.joint_names = tuple(joint_names)
        #: largest deviation [rad] between a trajectory's start and the measured joints (policy
        #: `motion.start_tolerance_rad`)
        self.start_tolerance_rad = float(start_tolerance_rad)
        self._last_stop_stamp: float | None = None
        self._stop_epoch = 0
        self._stop_epoch_lock = threading.Lock()  # stops come from any thread
        self._execution_epoch = 0  # the stop epoch the running execution was decided under
        self._gripper_epoch = 0  # the stop epoch the running gripper action was decided under
        self._opened = False
        self._closed = False
        self._cell = Cell()

    @property
    def last_stop_stamp(self) -> float | None:
        """Monotonic time [s] at which the latest stop took effect (no motion commanded after it),
        for backends that can tell (servo loops, one that records its own with
        `_record_stop_stamp`); None otherwise."""
        return self._latest_stop_stamp()

    def _latest_stop_stamp(self) -> float | None:
        """Hook: where this backend keeps the stamp of its latest stop (default: the recorded one)."""
        return self._last_stop_stamp

    def _record_stop_stamp(self, stamp: float) -> None:
        """For a backend that commands its own hold: the monotonic time [s] that hold took effect."""
        self._last_stop_stamp = stamp

    @property
    def stop_epoch(self) -> int:
        """How many stops have been issued (any path, any thread). A caller that decides to move
        notes it and passes it to `execute`, so a stop after its decision always wins."""
        return self._stop_epoch

    def _bump_stop_epoch(self) -> None:
        with self._stop_epoch_lock:
            self._stop_epoch += 1

    def _stop_landed(self) -> bool:
        """A stop was issued since the running execution was decided. `_execute` hooks check it
        under the lock their stop takes, atomically with handing the trajectory over."""
        return self._stop_epoch != self._execution_epoch

    def _gripper_stop_landed(self) -> bool:
        """Like `_stop_landed`, for the running gripper action (gripper parts check it under the
        lock their stop takes when they start the fingers)."""
        return self._stop_epoch != self._gripper_epoch

    def _admit(self, stop_epoch: int | None, what: str) -> int:
        """The stop epoch an actuation was decided under (now, if the caller gave none); refuses
        it (`StoppedBeforeStart`, nothing started) when a stop has been issued since."""
        epoch = self._stop_epoch if stop_epoch is None else stop_epoch
        if self._stop_epoch != epoch:
            raise StoppedBeforeStart(f"{what} not started: a stop was issued after it was decided")
        return epoch

    # ---------------------------------------------------------------- lifecycle
    @property
    def is_open(self) -> bool:
        return self._opened and not self._closed

    async def open(self) -> None:
        if self._opened:
            return
        await self._open()
        self._opened = True
        if not self._closed:  # (a close before the open: it stays closed)
            self._arm_event(ArmEvent.OPEN)
        try:
            self._start_watchdog()
        except BaseException:
            await self.close()
            raise
        logger.info("backend %s opened", self.name)

    async def close(self) -> None:
        """Stop everything and release resources. Safe to call twice or before `open`."""
        if self._closed:
            return
        self._closed = True
        try:
            await self._stop_and_release()
        finally:
            self._arm_event(ArmEvent.CLOSE)
        watchdog = self._watchdog
        if watchdog is not None:  # (it reported nothing since `_closed`: see `_lose_worker`)
            with anyio.CancelScope(shield=True):
                await anyio.to_thread.run_sync(watchdog.stop)
        logger.info("backend %s closed", self.name)

    async def _stop_and_release(self) -> None:
        if self._opened:
            # shielded (close often runs in a cancelled task: SIGTERM, disconnect) and bounded (a
            # hung stop must not keep the backend from closing)
            try:
                with anyio.fail_after(self.stop_timeout_s, shield=True):
                    await self._stop()
            except Exception:  # closing must not fail because the stop did
                logger.exception("backend %s: stop during close failed", self.name)
            with anyio.CancelScope(shield=True):
                await self._close()

    def _require_open(self) -> None:
        if not self.is_open:
            raise BackendError(f"backend {self.name} is not open")
        if (failure := self.worker_failure) is not None:
            raise BackendError(failure)

    @property
    def cell(self) -> Cell:
        """The cell's optional parts (`armwarden.backends.parts`); a backend sets it in its
        constructor (default: an arm with no parts)."""
        return self._cell

    @cell.setter
    def cell(self, cell: Cell) -> None:
        self._cell = cell

    @property
    def capabilities(self) -> Capabilities:
        """What the cell offers: read from its parts."""
        return self.cell.capabilities

    # ---------------------------------------------------------------- state
    async def read_joint_state(self) -> JointState:
        self._require_open()
        published = self._latest_joint_state()
        if published is not None:
            return published
        return await self._bounded("joint state read", self.read_timeout_s, self._read_joint_state)

    async def read_joint_states_since(self, stamp: float | None) -> tuple[JointState, ...]:
        """Every sample stamped after `stamp`, oldest first, the newest last; never empty.

        A backend that keeps a history (`_joint_states_since`) gives each sample it still holds,
        or its newest kept sample when none is newer (its stamp then is not after `stamp`: no new
        sample); a first read (`stamp` None) gets that newest kept sample too. The latest published
        sample can be newer than any kept one (the CAN backend keeps only states every actuator
        answered): a first read that got it would find the next one older (found by CI). One that
        keeps none, and a history still empty, give the latest published sample alone."""
        self._require_open()
        # no kept sample is newer than +inf: the history's newest comes back alone
        history = self._joint_states_since(math.inf if stamp is None else stamp)
        if history:
            return tuple(history)
        return (await self.read_joint_state(),)

    # ---------------------------------------------------------------- motion
    async def execute(
        self, trajectory: JointTrajectory, progress: ProgressCallback | None = None, *, stop_epoch: int | None = None
    ) -> ExecutionResult:
        """Run `trajectory` exactly. Any failure or cancellation stops the arm before it propagates.

        `stop_epoch` is the `stop_epoch` the caller saw when it decided to move (default: now): if
        any stop was issued since, nothing moves and the result is "stopped before it started".
        """
        self._require_open()
        self._execution_epoch = self._stop_epoch if stop_epoch is None else stop_epoch
        try:
            self.check_trajectory(trajectory)
            await self._check_start(trajectory)
            if self._stop_landed():
                return ExecutionResult(False, PREEMPTED, (await self.read_joint_state()).positions.copy())
            if not self.reports_motion_events:
                self._report_execute()
            result = await self._execute(trajectory, progress or (lambda _fraction: None))
            if (failure := self.worker_failure) is not None:  # its stop ended the run: a fault, not a stop
                raise BackendError(f"execution aborted: {failure}")
            if not self.reports_motion_events:  # (a stop from another thread may have held it already)
                self._arm_event_if(ArmEvent.FINISH if result.completed else ArmEvent.STOP, ArmState.MOVING)
            return result
        except BaseException:
            with anyio.CancelScope(shield=True):
                try:
                    await self.stop()
                except BackendError:  # keep the original exception: the caller stops again and latches
                    logger.exception("backend %s: stop after an interrupted execution failed", self.name)
            raise

    def _report_execute(self) -> None:
        """The arm moves. After a fault or damping the Guard executes only once a human reset the
        e-stop: for a backend that does not report its own recovery, that reset is the recovery."""
        self._arm_event_if(ArmEvent.RECOVER, ArmState.DAMPED, ArmState.FAULTED)
        self._arm_event(ArmEvent.EXECUTE)

    def check_trajectory(self, trajectory: JointTrajectory) -> None:
        """Refuse (`BackendError`) a trajectory this backend cannot run as given: other joints, a
        wrong shape, non-finite values, or times that do not start at 0 and never decrease."""
        if tuple(trajectory.joint_names) != self.joint_names:
            raise BackendError(f"trajectory joints {trajectory.joint_names} do not match backend joints {self.joint_names}")
        times, positions = np.asarray(trajectory.times), np.asarray(trajectory.positions)
        n = len(self.joint_names)
        if times.ndim != 1 or len(times) == 0 or positions.shape != (len(times), n):
            raise BackendError(f"malformed trajectory: times {times.shape}, positions {positions.shape}, {n} joints")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(positions))):
            raise BackendError("malformed trajectory: non-finite time or position")
        if times[0] != 0.0 or np.any(np.diff(times) < 0):
            raise BackendError("malformed trajectory: times must start at 0 and never decrease")

    async def _check_start(self, trajectory: JointTrajectory) -> None:
        """Refuse a trajectory that does not start where the arm is (within `start_tolerance_rad`)."""
        q_now = (await self.read_joint_state()).positions
        deviation = np.abs(trajectory.start - q_now)
        worst = int(np.argmax(deviation))
        if not deviation[worst] <= self.start_tolerance_rad:
            raise BackendError(
                f"trajectory starts {deviation[worst]:.4f} rad away from the arm on {self.joint_names[worst]} "
                f"(start {trajectory.start[worst]:.4f}, measured {q_now[worst]:.4f}, "
                f"tolerance {self.start_tolerance_rad:g} rad)"
            )

    async def stop(self) -> None:
        """Stop arm and gripper now. Raises `BackendError` if the stop could not be issued."""
        await self._stop_bounded(self._stop, "stop")

    def stop_now(self) -> None:
        """Stop arm and gripper from any thread, without the event loop; the arm is held when it
        returns. Raises `BackendError` if the stop could not be issued. No-op unless open."""
        self._stop_synchronously(self._stop_now, "stop")

    async def emergency_stop(self) -> None:
        """The e-stop's stop of arm and gripper (`armwarden.backends.hooks`, "Rules every backend follows"); like `stop`.
        Raises `BackendError` if the stop could not be issued."""
        await self._stop_bounded(self._emergency_stop, "e-stop")

    async def _stop_bounded(self, hook: Callable[[], Awaitable[None]], what: str) -> None:
        self._bump_stop_epoch()
        if not self._opened or self._closed:
            return
        try:
            with anyio.fail_after(self.stop_timeout_s):
                await hook()
            self._report_stop()
        except TimeoutError as exc:
            raise BackendTimeout(f"backend {self.name}: {what} not confirmed within {self.stop_timeout_s} s") from exc
        except BackendError:
            raise
        except Exception as exc:
            raise BackendError(f"backend {self.name}: {what} failed: {exc}") from exc

    def _report_stop(self) -> None:
        """A stop hook returned: the arm is held (damped drives stay damped: see the table)."""
        if not self.reports_motion_events:
            self._arm_event(ArmEvent.STOP)

    def emergency_stop_now(self) -> None:
        """The e-stop's stop from any thread, without the event loop; like `stop_now`. Raises
        `BackendError` if the stop could not be issued. No-op unless open."""
        self._stop_synchronously(self._emergency_stop_now, "e-stop")

    def _stop_synchronously(self, hook: Callable[[], None], what: str) -> None:
        self._bump_stop_epoch()
        if not self._opened or self._closed:
            return
        try:
            hook()
            self._report_stop()
        except BackendError:
            raise
        except Exception as exc:
            raise BackendError(f"backend {self.name}: {what} failed: {exc}") from exc

    async def _bounded(self, what: str, timeout_s: float, call: Callable[[], Awaitable[T]], *, actuating: bool = False) -> T:
        """Await `call()` under a deadline; a miss is a `BackendTimeout` (after a stop if `actuating`)."""
        try:
            with anyio.fail_after(timeout_s):
                return await call()
        except BackendTimeout:
            raise
        except TimeoutError as exc:
            if actuating:  # whatever it started may still be moving: fail closed
                with anyio.CancelScope(shield=True):
                    try:
                        await self.stop()
                    except BackendError:
                        logger.exception("backend %s: stop after a missed %s deadline failed", self.name, what)
            raise BackendTimeout(f"backend {self.name}: {what} did not finish within {timeout_s:g} s") from exc
