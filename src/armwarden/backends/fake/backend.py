"""The fake backend: a kinematic arm and a parallel gripper, deterministic, no dependency beyond the core.

`FakeBackend` drives the arm's joints, frames, home and kinematics (`arm.py`) and builds its cell of
parts (armwarden.backends.parts): the fingers (`gripper.py`), the cameras (`cameras.py`), the
simulated ros2_control set-up (`controllers.py`: the profile's controllers and ROS graph, a generic
set for a user's URDF) and the contact parts (`contact.py`: wrench, collision thresholds, error
recovery).

The arm is kinematic and driven by a `ServoLoop` (armwarden.backends.servo) ticking every
`control_period_s` (≤ 1 ms) on its own thread: each tick commands `trajectory.sample(elapsed ×
speedup)`, the same linear interpolation the envelope checked, so the final positions equal the
goal exactly. The fake's "command" is publishing the sample; a stop publishes the hold in the
thread that issues it, before `stop()`/`stop_now()` returns, and no tick computed before it is
published after it. A kinematic arm has no inertia: it is still from that instant, which
`last_stop_stamp` records (monotonic clock).

Joint torques (`efforts.py`): every published joint state carries the torques [N·m] the motors
would measure for the commanded motion — the model's inverse dynamics of the setpoint, gravity
included, less the external torque of a test's push (`push` / `release_push`), with optional
seeded Gaussian noise (`joint_torque_noise_nm`); `joint_torques=False` leaves them out (None).
Computed on the servo thread for each sample, like the wrench.

Contact. With `table_height_m` set, the estimated wrench is the table's contact force
(`arm.table_contact_force_n`) at the TCP the servo thread computes with its own model. The wrench
is computed on the servo thread and stamped with that tick's monotonic time.

The gripper (`gripper.FakeFingers`) is a width model on the event loop, time-scaled, frozen by a
stop from any thread. Cameras render a small top view with Pillow (none without it).

Fault injection for tests: `fail_stop` (stop raises and is not delivered), `freeze_wrench` (the
wrench stops updating, so its stamp stops advancing), `freeze_joint_torques` (the joint states'
torques repeat their last values while positions move on), `nan_joint_torques` (they read NaN), `stall_wrench_s` (wrench reads take that
long), `fault` (the robot is in an error state until `error_recovery`), `object_width_m` (the
object between the fingers). All of them are attributes that can be changed at run time; they
live in `knobs` (`FakeKnobs`), shared with the parts, with the records `actuation_commands`,
`collision_thresholds` and `last_grasp_force_n`.
The control thread dies like any backend thread (`inject_worker_failure("control", ...)`): a
latched fault, every later call refused; so does a control thread that hangs (no tick within its
deadline, `inject_worker_hang`): the watchdog holds the arm from its own thread. The evaluation's
injected death (`inject_death`, `armwarden.backends.death`) is that same death of the control thread.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from armwarden.backends.fake.arm import ArmKinematics, arm_setup, require, require_positive, table_contact_force_n
from armwarden.backends.fake.cameras import HAVE_PILLOW, FakeCameras, TopView
from armwarden.backends.fake.config import Config
from armwarden.backends.fake.contact import FakeRecovery, FakeThresholds, FakeWrench
from armwarden.backends.fake.controllers import FakeControllerManager, FakeControllers, FakeGraph
from armwarden.backends.fake.efforts import Efforts, JointTorques
from armwarden.backends.fake.gripper import FakeFingers
from armwarden.backends.fake.knobs import FakeKnobs, Knob
from armwarden.backends.parts import Cell
from armwarden.backends.servo import ServoBackend, ServoLoop, Setpoint, frozen
from armwarden.backends.state_history import JointStateHistory
from armwarden.backends.values import ControllerInfo, ExecutionResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState, Wrench
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel
from armwarden.robots import builtin_profile

if TYPE_CHECKING:
    from armwarden.policy import Policy


class FakeBackend(ServoBackend):
    """Kinematic arm and gripper driven by a servo loop (see the module docstring)."""

    name = "fake"
    worker_threads = ("control",)  # the servo loop

    # the test API (fault injections and records, module docstring): attributes of the shared `knobs`
    fail_stop = Knob[bool]()
    freeze_wrench = Knob[bool]()
    freeze_joint_torques = Knob[bool]()
    nan_joint_torques = Knob[bool]()
    stall_wrench_s = Knob[float]()
    fault = Knob[bool]()
    fault_reason = Knob[str]()
    object_width_m = Knob[float | None]()
    actuation_commands = Knob[int]()
    collision_thresholds = Knob[tuple[float, float] | None]()
    last_grasp_force_n = Knob[float | None]()

    def __init__(
        self,
        *,
        robot: RobotModel | None = None,
        description: str = "builtin:fr3",
        joint_names: Sequence[str] | None = None,
        base_frame: str | None = None,
        tcp_frame: str | None = None,
        home: Sequence[float] | None = None,
        speedup: float = 1.0,
        control_period_s: float = 0.001,
        table_height_m: float | None = None,
        table_stiffness_n_per_m: float = 20000.0,
        cameras: Sequence[str] = ("wrist", "scene"),
        controllers: Sequence[ControllerInfo | tuple[str, str, str]] | None = None,
        gripper_max_width_m: float = 0.08,
        wrench: bool = True,
        fail_stop: bool = False,
        freeze_wrench: bool = False,
        stall_wrench_s: float = 0.0,
        start_tolerance_rad: float = 0.05,
        joint_torques: bool = True,
        joint_torque_noise_nm: float = 0.0,
        joint_torque_noise_seed: int = 0,
    ) -> None:
        profile = builtin_profile(description)
        arm = arm_setup(profile, description, robot, joint_names, base_frame, tcp_frame, home)
        super().__init__(arm.joint_names, start_tolerance_rad=start_tolerance_rad)
        require(math.isfinite(speedup) and speedup > 0, f"speedup must be a positive number, got {speedup}")
        require(
            math.isfinite(control_period_s) and 0 < control_period_s <= 0.001,
            f"control_period_s must be in (0, 0.001] s, got {control_period_s}",
        )
        require(table_height_m is None or math.isfinite(table_height_m), f"table_height_m must be finite, got {table_height_m}")
        require_positive(table_stiffness_n_per_m, "table_stiffness_n_per_m")
        require_positive(gripper_max_width_m, "gripper_max_width_m")
        require(math.isfinite(stall_wrench_s) and stall_wrench_s >= 0, f"stall_wrench_s must be ≥ 0, got {stall_wrench_s}")

        self.robot = robot  # the event loop's model; the servo thread computes with `arm.model`
        self._kinematics = ArmKinematics(arm.model)
        #: the servo thread's joint torques (None: the fake does not measure them)
        self.joint_torques = JointTorques(arm.model, joint_torque_noise_nm, joint_torque_noise_seed) if joint_torques else None
        self._last_efforts: Efforts | None = None  # what the servo thread last computed (freeze_joint_torques)
        self.control_period_s = float(control_period_s)
        self.table_height_m = table_height_m
        self.table_stiffness_n_per_m = float(table_stiffness_n_per_m)
        self.gripper_max_width_m = float(gripper_max_width_m)
        #: the fault injections and records the parts share (the `Knob` attributes above)
        self.knobs = FakeKnobs(fail_stop=fail_stop, freeze_wrench=freeze_wrench, stall_wrench_s=stall_wrench_s)
        self._controllers = FakeControllers.for_profile(profile, controllers)

        self._wrench = (self._contact_force_n(self._compute_tcp(arm.home)), time.monotonic())
        #: every tick's joint state, for the contact observer (`_joint_states_since`): polled alone,
        #: the samples lie a monitor period apart, and on a sped-up fake that is more of the arm's
        #: motion than the observer integrates in one interval
        self.joint_history = JointStateHistory(FAKE_HISTORY_SAMPLES)
        self.servo = ServoLoop(self, arm.home, period_s=self.control_period_s, speedup=float(speedup), name="fake backend")
        self._loop: asyncio.AbstractEventLoop | None = None

        #: the fingers (their motions run on the event loop; a stop freezes them from any thread)
        self.fingers = FakeFingers(self.gripper_max_width_m, lambda: self.speedup, self._gripper_stop_landed,
                                   lambda: self._loop, self.knobs)
        camera_names = tuple(cameras) if HAVE_PILLOW else ()
        self.cell = Cell(
            gripper=self.fingers,
            cameras=FakeCameras(camera_names, self._top_view) if camera_names else None,
            wrench=FakeWrench(self._wrench_sample, self.knobs) if wrench else None,
            controllers=FakeControllerManager(self._controllers, lambda: self.servo.busy, self.knobs),
            collision_thresholds=FakeThresholds(self.knobs),
            error_recovery=FakeRecovery(self._require_running, self.knobs),
            graph=FakeGraph(self._controllers, wrench=bool(wrench), cameras=camera_names),
            frames=tuple(robot.frame_names() if robot is not None else arm.model.frame_names()),
            joint_torques=joint_torques,
            time_scale=float(speedup),
            joint_state_interval_s=self.control_period_s,
        )

    # ================================================================ lifecycle
    @property
    def speedup(self) -> float:
        """Time scaling of arm and gripper motion, no unit (2 = twice as fast)."""
        return self.servo.speedup

    @property
    def control_thread(self) -> threading.Thread | None:
        """The servo thread (None before open)."""
        return self.servo.thread

    @property
    def tick_count(self) -> int:
        """Servo ticks run so far (the thread's heartbeat)."""
        return self.servo.tick_count

    async def _open(self) -> None:
        """Start the servo thread and return once it has published a state of its own (until
        then the only sample is the one taken at construction, which may already be stale)."""
        self._loop = asyncio.get_running_loop()
        await self.servo.start("armwarden-fake-control")

    async def _close(self) -> None:
        await self.servo.shutdown()

    def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
        return (self.servo.heartbeat("control"),)

    def _require_running(self) -> None:
        self.servo.require_running()

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        self._require_running()
        setpoint = self.servo.latest  # read-only arrays, replaced whole by each tick
        return self._joint_state(setpoint, setpoint.extra[2])

    def _joint_state(self, setpoint: Setpoint, efforts: Efforts | None) -> JointState:
        # following, the arm moves as a physical one would follow the path (`spread_motion`): the
        # velocity its measured torques belong to, never outside the segments' velocities
        spread = setpoint.spread
        velocities = spread.velocities if setpoint.following and spread is not None else setpoint.velocities
        return JointState(self.joint_names, setpoint.positions, velocities, setpoint.stamp,
                          efforts.published(setpoint) if efforts is not None else None)

    async def _read_joint_state(self) -> JointState:
        return self._latest_joint_state()

    def _joint_states_since(self, stamp: float) -> Sequence[JointState]:
        self._require_running()
        return self.joint_history.since_or_latest(stamp)

    def _wrench_sample(self) -> Wrench:
        """The wrench the servo thread last published (`FakeWrench`)."""
        self._require_running()
        force_z, stamp = self._wrench
        return Wrench(np.array([0.0, 0.0, force_z]), _ZERO3, stamp)

    def _top_view(self) -> TopView:
        """What the cameras show (`FakeCameras`): the latest sample, the fingers, the table."""
        setpoint = self.servo.latest
        return TopView(setpoint.stamp, setpoint.extra[0], self.fingers.state().width_m, self._wrench[0],
                       self.table_height_m)

    # ================================================================ pushing on the arm (tests)
    def push(self, frame: str, force_base: Sequence[float], point_in_frame: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Push on the arm from the next sample on, until `release_push`: a force `force_base` [N]
        (base frame) at `point_in_frame` [m] of the model frame `frame` (a link). The measured
        joint torques drop by Jᵀ F; the arm itself, kinematic, does not yield."""
        torques = self.joint_torques
        if torques is None:
            raise BackendError("this fake measures no joint torques (joint_torques=False)")
        torques.push = torques.make_push(frame, force_base, point_in_frame)

    def release_push(self) -> None:
        """Nothing pushes on the arm any more (from the next sample on)."""
        if self.joint_torques is not None:
            self.joint_torques.push = None

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        self.actuation_commands += 1
        self._require_running()
        if self.fault:
            raise BackendError(f"robot is in an error state ({self.fault_reason or 'fault'}); error recovery is needed")
        self._controllers.require_trajectory_active()
        # a cancelled caller is held at once, unless the injected fault says stops are lost
        return await self.servo.run(trajectory, progress, hold_on_exit=not self.fail_stop, preempted=self._stop_landed)

    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        if self.fail_stop:  # neither the arm nor the gripper hears this stop
            raise BackendError("injected fault: the stop command was not delivered (fail_stop=True)")
        try:
            self.servo.hold()
        finally:  # the fingers stop even if the arm's hold failed
            self._stop_fingers()
        self._require_running()  # held either way; a dead control thread is still reported as a failure

    # ================================================================ servo hooks (servo thread)
    def servo_prepare(self, setpoint: Setpoint) -> tuple[np.ndarray, float, Efforts | None]:
        """The TCP position, the contact force [N] and the joint torques at the setpoint."""
        self._worker_checkpoint("control")
        tcp = self._compute_tcp(setpoint.positions)
        return tcp, self._contact_force_n(tcp), self._efforts(setpoint)

    def _efforts(self, setpoint: Setpoint) -> Efforts | None:
        """The joint torques of `setpoint`, as the fault injections leave them (servo thread)."""
        if self.joint_torques is None:
            return None
        if self.freeze_joint_torques and self._last_efforts is not None:
            stuck = self._last_efforts.moving  # a stuck reading: the same values, whatever the arm does
            return Efforts(stuck, stuck)
        efforts = self.joint_torques.compute(setpoint)
        if self.nan_joint_torques:
            efforts = Efforts(_nan_like(efforts.moving), _nan_like(efforts.still))
        self._last_efforts = efforts
        return efforts

    #: the fake arm is on its trajectory even while this thread is late (`ServoHooks`)
    records_missed_samples = True

    def servo_measure_missed(self, setpoint: Setpoint) -> Efforts | None:
        return self._efforts(setpoint)

    def servo_record(self, setpoint: Setpoint) -> None:
        self.joint_history.append(self._joint_state(setpoint, setpoint.extra))

    def servo_command(self, setpoint: Setpoint) -> None:
        self.joint_history.append(self._joint_state(setpoint, setpoint.extra[2]))
        if not self.freeze_wrench:  # a frozen sensor repeats its last sample, stamp included
            self._wrench = (setpoint.extra[1], setpoint.stamp)

    def servo_failed(self, error: BaseException) -> None:
        self.fault, self.fault_reason = True, f"control thread failed: {error!r}"
        self._worker_died("control", error)  # reported: the Guard latches and records it

    def why_no_injected_death(self) -> str | None:
        return None  # a simulation, always

    def _inject_death(self) -> str:
        """Evaluation only (`armwarden.backends.death`): the control thread dies at its next tick."""
        return self._kill_worker("control")

    def _compute_tcp(self, q: np.ndarray) -> np.ndarray:
        """TCP position in the base frame (servo thread side; a test replaces it to break the thread)."""
        return self._kinematics.tcp_position(q)

    def _contact_force_n(self, tcp_position: np.ndarray) -> float:
        """The table's force [N]; reads the attributes, which a test may change at run time."""
        return table_contact_force_n(tcp_position, self.table_height_m, self.table_stiffness_n_per_m)


_ZERO3 = frozen(np.zeros(3))
#: the fake's history: 4 s at its 1 kHz, so a Guard whose event loop stalled on a loaded test
#: machine still finds every sample since its last read (a sped-up fake moves 10x further meanwhile)
FAKE_HISTORY_SAMPLES = 4096


def _nan_like(values: np.ndarray) -> np.ndarray:
    return frozen(np.full(values.shape, np.nan))


def create_backend(robot: RobotModel, policy: Policy, config: Config) -> FakeBackend:
    """Registry factory: the fake arm for `policy`'s robot, with `config`'s options."""
    return FakeBackend(
        robot=robot,
        description=policy.robot.description,
        home=list(policy.robot.home_joint_positions),
        start_tolerance_rad=policy.motion.start_tolerance_rad,
        **config.model_dump(),
    )


__all__ = ["FakeBackend", "create_backend"]
