"""`python scripts/bench.py contact [--backend can]`: contact detection from joint torques, on the
MuJoCo FR3 (the default) or on the CAN backend's emulated arm (examples/can_sim.yaml).

One `Bench` for both: what differs between them is a `Cell` (`MujocoCell`, `CanCell`): opening the
backend with a payload the hand carries, telling the true external torques, and pushing on a link.
The Guard's own pieces — `ForceMonitor` over `JointTorqueContact` with the observer `observer_for`
builds from the bundled policy (`force.source: joint_torques`), reading the backend's
`read_joint_states_since`, polled at the policy's monitor rate like `ForceMonitor.run` — run
around `backend.execute` at speedup 1, so the observer sees the real, irregular sample intervals.
The Guard path itself is covered by tests (tests/server/test_contact_mujoco.py,
tests/scenarios/test_contact.py on every backend); this measures. Every motion is planned and
checked by the envelope (`plan_and_check`) at the policy's maximum velocity and acceleration
scaling. Seeded.

1. Stop latency: the hand moves down into a box welded to the world that the policy does not
   know. Contact onset (the first physics sample in which a robot geom overlaps the box, seen
   by a hook on the physics thread's measurement) → the stop commanded (the instant the
   monitor's violation handler calls the backend's e-stop), p50/p95; the peak contact force
   per trial (|Measured.force|, the hand's F/T reading, from onset until the arm is at rest).
2. Detection threshold: random motions; mid-motion a force F pushes at the TCP in a random
   direction for `PUSH_S`: detected (a violation while it pushes, or within one monitor period
   of its release) or not, per F; the smallest F detected in ≥ 95 % of trials; and per joint the
   RMS error of the estimate against the true external torque (`Measured.external_efforts`)
   over the pushes, all samples and once the observer has settled (`SETTLED_AFTER_S` in).
3. False alarms: random safe motions with nothing touching the arm, payload 0 and 1 kg (the
   kilogram declared in `force.joint_torques.payload_kg` and carried at the TCP: a point mass at
   the MuJoCo model's TCP body, `simulate.payload_kg` on the emulator): violations, and per joint
   the peak |estimate| (the margin to each limit).

On CAN the arm is the emulator's Pinocchio body (2 % mass error, torque noise, the friction of
can_sim.yaml), stepped in real time (speedup 1) on its own thread beside the servo loop; the 1st
figure is MuJoCo's alone (the emulator has no obstacles to run into). The truth there is
`true_external_torques()` read the moment the monitor reads the joint states, the newest of which
is a servo period or two older: the push's first samples are misaligned by that much (the settled
RMS is not).

The interpreter runs as `armwarden serve` runs it (its GIL switch interval and frozen, less
frequent garbage collection): the monitor shares the interpreter lock with the backend's threads.

A backend fault mid-run (a servo or physics thread starved past its deadline on a loaded machine,
which the backend rightly treats as a fault) ends that trial only: it is counted, a fresh cell is
opened and the run goes on.
"""

# mujoco ships compiled modules without type stubs (see src/armwarden/backends/mujoco/model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import math
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from bench_common import bench_policy, percentiles  # scripts/_bench is on sys.path (scripts/bench.py puts it there)

from armwarden.core.errors import BackendError
from armwarden.core.state import JointState

#: the CAN backend's emulated arm (the example config `armwarden serve --backend can` is shown with)
CAN_SIM = Path(__file__).resolve().parents[2] / "examples" / "can_sim.yaml"

SEED = 28
#: the box the policy does not know: top height [m], full size [m] (centred under the home TCP)
BOX_TOP_Z_M = 0.36
BOX_SIZE_M = (0.12, 0.12, 0.10)
HOME_TCP_X_M = 0.3069
#: how deep below the box top the latency trials aim the TCP [m] (the plan would end inside it)
AIM_BELOW_TOP_M = 0.11
#: TCP forces [N] scanned for the detection threshold
FORCES_N = (5.0, 7.5, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0)
PUSH_S = 0.3
#: the observer's first-order lag: an estimate this long after a push began counts as settled
SETTLED_AFTER_S = 0.06
#: random goals: each joint within this of home [rad] (kept inside the joint limits)
GOAL_SPREAD_RAD = 0.35
DETECTED_SHARE = 0.95
PAYLOAD_KG = 1.0
#: an arm slower than this counts as at rest after a stop [rad/s]
REST_RAD_S = 1e-3


@dataclass
class SampleHook:
    """Sees every physics sample on the physics thread (`install_hook`): while armed, the first
    sample in which a robot geom touches one of `obstacle_geoms`, and from then on the peak
    contact force between them (MuJoCo's own contact forces, summed as a vector) and the peak
    |Measured.force| (the hand's F/T reading, inertia of a braking hand included)."""

    robot_geoms: np.ndarray
    obstacle_geoms: np.ndarray
    onset_stamp: float | None = None
    peak_contact_n: float = 0.0
    peak_sensor_n: float = 0.0
    armed: bool = False

    def seen(self, model: Any, data: Any, sample: Any) -> None:
        if not self.armed or not self.obstacle_geoms.any():
            return
        import mujoco

        total = np.zeros(3)
        touching = False
        wrench = np.zeros(6)
        for i in range(data.ncon):
            contact = data.contact[i]
            g1, g2 = int(contact.geom1), int(contact.geom2)
            if not ((self.robot_geoms[g1] and self.obstacle_geoms[g2]) or (self.robot_geoms[g2] and self.obstacle_geoms[g1])):
                continue
            touching = touching or contact.dist <= 0.0
            mujoco.mj_contactForce(model, data, i, wrench)
            total += np.asarray(contact.frame).reshape(3, 3).T @ wrench[:3]
        if self.onset_stamp is None and touching:
            self.onset_stamp = sample.stamp
        if self.onset_stamp is not None:
            self.peak_contact_n = max(self.peak_contact_n, float(np.linalg.norm(total)))
            self.peak_sensor_n = max(self.peak_sensor_n, float(np.linalg.norm(sample.force)))

    def arm(self) -> None:
        self.onset_stamp, self.peak_contact_n, self.peak_sensor_n, self.armed = None, 0.0, 0.0, True


def install_hook(backend: Any, base_body: str, obstacle_body: str) -> SampleHook:
    """A `SampleHook` on `backend`'s measurement (the physics thread calls it after every step)."""
    model = backend.sim.model
    base = model.body(base_body).id
    robot = model.body_rootid[model.geom_bodyid] == model.body_rootid[base]
    obstacle = model.geom_bodyid == model.body(obstacle_body).id
    hook = SampleHook(robot, obstacle)
    meter = backend.arm._meter  # a benchmark's probe into the physics thread
    measure = meter.measure

    def measured(data: Any, *args: Any, **kwargs: Any) -> Any:
        sample = measure(data, *args, **kwargs)
        hook.seen(model, data, sample)
        return sample

    meter.measure = measured
    return hook


def add_payload(backend: Any, tcp_body: str, mass_kg: float) -> None:
    """A point mass at the TCP body of the compiled model, before the physics starts (the hand
    carries it; the servos' gravity compensation counts it like every arm body)."""
    import mujoco

    model = backend.sim.model
    body = model.body(tcp_body).id
    model.body_mass[body] = mass_kg
    model.body_ipos[body] = 0.0
    model.body_inertia[body] = 1e-6  # a point mass: the least MuJoCo integrates well
    model.body_gravcomp[body] = 1.0
    mujoco.mj_setConst(model, mujoco.MjData(model))  # subtree masses and the rest derived from masses


@dataclass
class Run:
    """One monitored execution: the first violation (and when the handler ran), the estimates."""

    violation: Any = None
    stop_stamp: float | None = None
    completed: bool = False
    #: the monitor had no usable baseline (a stale or lost reading): the Guard refuses such a motion
    #: (NO_WRENCH) and the bench did not move; `violation` says why
    refused: bool = False
    peaks: np.ndarray | None = None
    #: (stamp, estimated external torques, true external torques, the TCP force estimate where it
    #: is trusted else NaN) per monitor sample (the stamp: the truth's)
    samples: list[tuple[float, np.ndarray, np.ndarray, float]] = field(default_factory=list)
    #: the stamp of every joint state the monitor's reads returned (more than one a read from a
    #: backend that keeps a history of its samples)
    state_stamps: list[float] = field(default_factory=list)


class Cell(ABC):
    """What the bench needs of a simulated arm beyond the backend contract (see the module
    docstring): each subclass opens its backend at speedup 1 with the policy and a payload the
    hand carries, tells the true external torques, and pushes."""

    #: how the report names the cell
    title: str
    #: the figures it can give: "latency" needs obstacles in the simulation
    figures: tuple[str, ...] = ("detection", "false_alarms")

    def __init__(self, backend: Any) -> None:
        self.backend = backend

    @classmethod
    @abstractmethod
    def build(cls, policy: Any, runtime: Any, payload_kg: float, objects: list[dict[str, Any]]) -> Cell:
        """The cell for `policy`, not yet open: `payload_kg` at the TCP (the policy declares it too),
        `objects` fixed in the scene (only a cell with "latency" among its `figures` takes any)."""

    async def state(self) -> JointState:
        """The latest joint state, as the Guard reads it."""
        return await self.backend.read_joint_state()

    @abstractmethod
    def truth(self) -> tuple[float, np.ndarray]:
        """The external joint torques [N·m] acting on the arm in the newest simulated instant, and
        that instant's time on the monotonic clock [s]: what the observer estimates, never shown to it."""

    @abstractmethod
    def push(self, frame: str, force_base: np.ndarray) -> None:
        """Push with `force_base` [N] (base frame) at the origin of `frame` until `release_push`."""

    @abstractmethod
    def release_push(self) -> None: ...

    async def open(self) -> None:
        await self.backend.open()

    async def close(self) -> None:
        await self.backend.close()


class MujocoCell(Cell):
    """The MuJoCo FR3 (its own contact dynamics and its `Measured.external_efforts` as the truth)."""

    title = "MuJoCo FR3"
    figures = ("latency", "detection", "false_alarms")

    @classmethod
    def build(cls, policy: Any, runtime: Any, payload_kg: float, objects: list[dict[str, Any]]) -> Cell:
        from armwarden.backends import create_backend

        backend = create_backend("mujoco", runtime.robot, policy, {"speedup": 1.0, "objects": objects})
        if payload_kg > 0:
            add_payload(backend, runtime.robot.tcp_frame, payload_kg)
        return cls(backend)

    def truth(self) -> tuple[float, np.ndarray]:
        measured = self.backend.arm.measured  # the newest physics sample
        return float(measured.stamp), np.asarray(measured.external_efforts, dtype=float).copy()

    def push(self, frame: str, force_base: np.ndarray) -> None:
        self.backend.push(frame, force_base.tolist())

    def release_push(self) -> None:
        self.backend.release_push()


class CanCell(Cell):
    """The CAN backend on the emulated arm of examples/can_sim.yaml, on a virtual bus of its own,
    with the example's own timeouts (the daemon's, not the test harness's relaxed ones): a starved
    servo loop is a fault here as it would be in the daemon, and the bench counts it."""

    title = "CAN backend, emulated arm (examples/can_sim.yaml: 2 % mass error, torque noise, friction)"

    @classmethod
    def build(cls, policy: Any, runtime: Any, payload_kg: float, objects: list[dict[str, Any]]) -> Cell:
        import uuid

        import yaml

        from armwarden.backends import create_backend

        if objects:
            raise ValueError("the CAN emulator has no obstacles: the stop-latency figure is MuJoCo's")
        document = yaml.safe_load(CAN_SIM.read_text())
        document["bus"]["channel"] = f"armwarden-contact-bench-{uuid.uuid4().hex}"  # one name shares frames
        document["simulate"] |= {"speedup": 1.0, "payload_kg": payload_kg, "payload_com_m": [0.0, 0.0, 0.0]}
        return cls(create_backend("can", runtime.robot, policy, document))

    def truth(self) -> tuple[float, np.ndarray]:
        return time.monotonic(), self._emulator().true_external_torques()  # its last step: now, give or take 1 ms

    def push(self, frame: str, force_base: np.ndarray) -> None:
        self._emulator().push(frame, force_base.tolist())

    def release_push(self) -> None:
        self._emulator().release_push()

    def _emulator(self) -> Any:
        emulator = self.backend.emulator
        if emulator is None:
            raise RuntimeError("the CAN backend runs no emulator (is it open?)")
        return emulator


#: the cells `--backend` chooses from
CELLS: dict[str, type[Cell]] = {"mujoco": MujocoCell, "can": CanCell}


class Bench:
    """One cell (speedup 1) with the policy's planner, envelope and contact monitor."""

    def __init__(self, policy: Any, cell: Cell, runtime: Any, rng: np.random.Generator) -> None:
        self.policy, self.cell, self.runtime, self.rng = policy, cell, runtime, rng
        self.backend = cell.backend
        self.names = tuple(policy.robot.joint_names)
        self.home = np.asarray(policy.robot.home_joint_positions, dtype=float)
        self.scaling = {"velocity_scaling": policy.motion.max_velocity_scaling,
                        "acceleration_scaling": policy.motion.max_acceleration_scaling}
        self.refused = 0

    async def here(self) -> np.ndarray:
        return np.asarray((await self.cell.state()).positions, dtype=float).copy()

    async def plan_joints(self, goal: np.ndarray) -> Any:
        """The checked trajectory from here to `goal`, or None (refused by planner or envelope)."""
        from armwarden.guard.planning import plan_and_check

        outcome, report = plan_and_check(self.runtime, "joints", await self.here(),
                                         {"joint_positions": goal.tolist(), **self.scaling})
        if outcome.trajectory is None or report is None or any(v.is_hard for v in report.violations):
            self.refused += 1
            return None
        return outcome.trajectory

    async def plan_tcp(self, position: tuple[float, float, float]) -> Any:
        from armwarden.guard.planning import plan_and_check
        from armwarden.planning.planners import PoseTarget

        target = PoseTarget(np.asarray(position, dtype=float), self.backend_tcp_rotation())
        outcome, _report = plan_and_check(self.runtime, "pose", await self.here(), {"target": target, **self.scaling})
        if outcome.trajectory is None:  # the box is unknown to the envelope: its verdict is not asked
            raise RuntimeError(f"no plan to {position}: {[v.detail for v in outcome.violations]}")
        return outcome.trajectory

    def backend_tcp_rotation(self) -> np.ndarray:
        return self.runtime.robot.tcp_pose(self.home).rotation

    def random_goal(self) -> np.ndarray:
        robot = self.runtime.robot
        margin = self.policy.motion.joint_limit_margin_rad + 0.02
        goal = self.home + self.rng.uniform(-GOAL_SPREAD_RAD, GOAL_SPREAD_RAD, len(self.names))
        return np.clip(goal, robot.lower + margin, robot.upper - margin)

    async def random_motion(self, min_duration_s: float = 0.0) -> Any:
        """A checked motion from here to a random goal near home at the policy's maximum scaling."""
        while True:
            trajectory = await self.plan_joints(self.random_goal())
            if trajectory is not None and trajectory.duration_s >= min_duration_s:
                return trajectory

    def monitor(self, run: Run) -> Any:
        """A fresh monitor built as the Guard builds one for `force.source: joint_torques`
        (`MotionRunner._reader`: whatever observer and reading rules it applies, this measures);
        its reads are recorded beside the cell's true external torques of the same sample."""
        from types import SimpleNamespace

        from armwarden.guard.execution import MotionRunner
        from armwarden.safety.force import ForceMonitor

        latest: list[tuple[float, np.ndarray] | None] = [None]

        async def read_joint_states_since(stamp: float | None) -> tuple[JointState, ...]:
            states = await self.backend.read_joint_states_since(stamp)
            latest[0] = self.cell.truth()  # the newest truth, kept beside the estimate these states give
            run.state_stamps.extend(float(state.stamp) for state in states)
            return states

        seen_by_guard = SimpleNamespace(read_joint_states_since=read_joint_states_since,
                                        capabilities=self.backend.capabilities)
        runner = MotionRunner(seen_by_guard, self.policy, None, clock=time.monotonic, audit=None,  # type: ignore[arg-type]
                              emergency_stop=None, stop_for=None, record=None, robot=self.runtime.robot)  # type: ignore[arg-type]
        contact_read = runner._reader("joint_torques")  # the Guard's own wiring, measured

        async def read() -> Any:
            estimate = await contact_read()
            torques = getattr(estimate, "external_torques_nm", None)
            truth = latest[0]
            if torques is not None and truth is not None:
                force = estimate.force_norm_n if estimate.wrench_trusted else math.nan  # type: ignore[union-attr]
                run.samples.append((truth[0], np.asarray(torques, dtype=float).copy(), truth[1], force))
            return estimate

        return ForceMonitor(runner.force_limits("joint_torques"), read)

    async def execute(self, trajectory: Any, *, stop_on_violation: bool,
                      during: Callable[[], Coroutine[Any, Any, None]] | None = None) -> Run:
        """`trajectory` with the monitor polling beside it (baseline first, one last check after,
        as the Guard does); the first violation stops the arm when `stop_on_violation`."""
        import anyio

        run = Run()
        monitor = self.monitor(run)
        baseline = await monitor.baseline()
        from armwarden.safety.force import ForceViolation

        if isinstance(baseline, ForceViolation):
            run.violation, run.refused = baseline, True
            return run

        async def found(violation: Any) -> None:
            if run.violation is None:
                run.violation = violation
                if stop_on_violation:
                    run.stop_stamp = time.monotonic()  # the instant the handler calls the e-stop
                    await self.backend.emergency_stop()

        async def poll() -> None:  # `ForceMonitor.run`, carrying on past a violation to see the peaks
            while True:
                violation = await monitor.check_once()
                if violation is not None:
                    await found(violation)
                    if stop_on_violation:
                        return
                await anyio.sleep(monitor.limits.period_s)

        result = None
        async with anyio.create_task_group() as group:
            group.start_soon(poll)
            if during is not None:
                group.start_soon(during)
            result = await self.backend.execute(trajectory)
            group.cancel_scope.cancel()
        if run.violation is None and (final := await monitor.check_once()) is not None:
            await found(final)
        run.completed = result is not None and result.completed
        run.peaks = monitor.max_observed_external_torques_nm
        return run

    async def wait_at_rest(self, timeout_s: float = 3.0) -> None:
        import anyio

        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if float(np.max(np.abs((await self.cell.state()).velocities))) < REST_RAD_S:
                return
            await anyio.sleep(0.005)  # published by the physics or servo thread: nothing to await

    async def move_plain(self, trajectory: Any) -> None:
        result = await self.backend.execute(trajectory)
        if not result.completed:
            raise RuntimeError(f"an unmonitored move did not complete: {result.reason}")


def joint_torques_section(limits_file: str | None) -> dict[str, Any]:
    """Policy overrides for `force.joint_torques`: none (the bundled section), or the section in
    `limits_file` (what `armwarden calibrate-contact` writes: the section alone, under
    `joint_torques:`, or under `force: joint_torques:`)."""
    if limits_file is None:
        return {}
    import yaml

    with open(limits_file, encoding="utf-8") as handle:
        document = yaml.safe_load(handle)
    if isinstance(document, dict) and isinstance(document.get("force"), dict):
        document = document["force"]
    if isinstance(document, dict) and isinstance(document.get("joint_torques"), dict):
        document = document["joint_torques"]
    if not isinstance(document, dict) or "max_external_torque_nm" not in document:
        raise ValueError(f"{limits_file} holds no force.joint_torques section")
    return {"force.joint_torques": document}


async def open_bench(backend: str, payload_kg: float, objects: list[dict[str, Any]], rng: np.random.Generator,
                     section: dict[str, Any] | None = None) -> Bench:
    """An open cell of kind `backend` (a key of `CELLS`) with the bundled policy at
    `force.source: joint_torques`, `section` over its `force.joint_torques`, and `payload_kg`
    declared in the policy and carried by the hand."""
    from armwarden.preflight import load_runtime_model

    if backend not in CELLS:
        raise ValueError(f"no contact bench cell {backend!r}; choose from {', '.join(CELLS)}")
    policy = bench_policy(**{"force.source": "joint_torques", **(section or {}),
                             "force.joint_torques.payload_kg": payload_kg})
    runtime = load_runtime_model(policy)
    cell = CELLS[backend].build(policy, runtime, payload_kg, objects)
    await cell.open()
    return Bench(policy, cell, runtime, rng)


async def reopened(bench: Bench, backend: str, payload_kg: float, objects: list[dict[str, Any]],
                   rng: np.random.Generator, section: dict[str, Any] | None) -> Bench:
    """A fresh cell after a backend fault (a physics or servo thread starved past its deadline on a
    loaded machine fails the backend, as it should): the fault is counted and the run goes on."""
    from contextlib import suppress

    with suppress(BackendError):
        await bench.cell.close()
    fresh = await open_bench(backend, payload_kg, objects, rng, section)
    fresh.refused = bench.refused
    return fresh


# ---------------------------------------------------------------------------------------- 1
async def stop_latency(trials: int, rng: np.random.Generator, section: dict[str, Any] | None = None) -> dict[str, Any]:
    """MuJoCo only: the cell must have a box to run into (see the module docstring)."""
    box = {"name": "unknown_box", "shape": "box", "position_m": [HOME_TCP_X_M, 0.0, BOX_TOP_Z_M - BOX_SIZE_M[2] / 2],
           "size_m": list(BOX_SIZE_M), "mass_kg": 1.0, "fixed": True}
    bench = await open_bench("mujoco", 0.0, [box], rng, section)
    hook = install_hook(bench.backend, bench.runtime.robot.base_frame, box["name"])
    latencies: list[float] = []
    contact_n: list[float] = []
    sensor_n: list[float] = []
    kinds: list[str] = []
    unstopped = faults = refused = 0
    try:
        for _ in range(trials):
            x = HOME_TCP_X_M + float(rng.uniform(-0.03, 0.03))
            y = float(rng.uniform(-0.03, 0.03))
            above = float(rng.uniform(0.42, 0.50))
            try:
                await bench.move_plain(await bench.plan_tcp((x, y, above)))
                hook.arm()
                run = await bench.execute(await bench.plan_tcp((x, y, BOX_TOP_Z_M - AIM_BELOW_TOP_M)),
                                          stop_on_violation=True)
                await bench.wait_at_rest()
                hook.armed = False
                if run.refused:
                    refused += 1
                elif run.stop_stamp is None or hook.onset_stamp is None:
                    unstopped += 1
                else:
                    latencies.append((run.stop_stamp - hook.onset_stamp) * 1e3)
                    contact_n.append(hook.peak_contact_n)
                    sensor_n.append(hook.peak_sensor_n)
                    kinds.append(run.violation.kind)
                await bench.move_plain(await bench.plan_tcp((x, y, above)))  # back up, off the box
            except BackendError:
                faults += 1
                bench = await reopened(bench, "mujoco", 0.0, [box], rng, section)
                hook = install_hook(bench.backend, bench.runtime.robot.base_frame, box["name"])
    finally:
        await bench.cell.close()
    return {"trials": trials, "not_stopped": unstopped, "backend_faults": faults, "no_baseline": refused,
            "latency_ms": percentiles(latencies),
            "peak_contact_force_n": percentiles(contact_n), "peak_hand_ft_n": percentiles(sensor_n),
            "kinds": {k: kinds.count(k) for k in sorted(set(kinds))}}


# ---------------------------------------------------------------------------------------- 2
async def detection(forces_n: tuple[float, ...], trials: int, rng: np.random.Generator,
                    section: dict[str, Any] | None = None, backend: str = "mujoco") -> dict[str, Any]:
    import anyio

    bench = await open_bench(backend, 0.0, [], rng, section)
    per_force: dict[str, dict[str, Any]] = {}
    #: per trial: the force, and in its window the peak |estimate| per joint and the peak trusted TCP force
    trials_seen: list[dict[str, Any]] = []
    errors_all: list[np.ndarray] = []
    errors_settled: list[np.ndarray] = []
    faults = refused = 0
    try:
        period = bench.policy.force.monitor_rate_hz ** -1
        for force in forces_n:
            detected = early = done = 0
            for _ in range(trials):
                trajectory = await bench.random_motion(min_duration_s=PUSH_S + 0.4)
                direction = rng.normal(size=3)
                direction /= np.linalg.norm(direction)
                window: list[float] = []
                start_s = (trajectory.duration_s - PUSH_S) / 2

                async def push(direction: np.ndarray = direction, window: list[float] = window,
                               start_s: float = start_s, force: float = force, cell: Bench = bench) -> None:
                    await anyio.sleep(start_s)
                    cell.cell.push(cell.runtime.robot.tcp_frame, force * direction)
                    window.append(time.monotonic())
                    try:
                        await anyio.sleep(PUSH_S)
                    finally:
                        cell.cell.release_push()
                        window.append(time.monotonic())

                try:
                    run = await bench.execute(trajectory, stop_on_violation=False, during=push)
                except BackendError:
                    faults += 1
                    bench = await reopened(bench, backend, 0.0, [], rng, section)
                    continue
                if run.refused:
                    refused += 1
                    continue
                done += 1
                if len(window) < 2:
                    raise RuntimeError("the motion ended before its push did")
                began, ended = window
                if run.violation is not None:
                    at = run.violation.at_mono
                    if at < began:
                        early += 1
                    elif at <= ended + period:
                        detected += 1
                joint_peak, wrench_peak = np.zeros(len(bench.names)), 0.0
                for stamp, estimate, truth, tcp_force in run.samples:
                    if began <= stamp <= ended + period:
                        joint_peak = np.fmax(joint_peak, np.abs(estimate))  # a lost reading (NaN) is no peak
                        wrench_peak = wrench_peak if math.isnan(tcp_force) else max(wrench_peak, tcp_force)
                    if began + 0.002 <= stamp <= ended and np.all(np.isfinite(estimate)):  # the push acts from
                        errors_all.append(estimate - truth)  # the step after `began`; a lost reading has no estimate
                        if stamp >= began + SETTLED_AFTER_S:
                            errors_settled.append(estimate - truth)
                trials_seen.append({"force_n": force, "joint_peak_nm": joint_peak.tolist(), "wrench_peak_n": wrench_peak})
            per_force[f"{force:g}"] = {"trials": done, "detected": detected, "share": detected / max(done, 1),
                                       "violations_before_push": early}
    finally:
        await bench.cell.close()
    threshold = next((float(f) for f in sorted(forces_n) if per_force[f"{f:g}"]["share"] >= DETECTED_SHARE), None)

    def rms(rows: list[np.ndarray]) -> list[float]:
        return [float(x) for x in np.sqrt(np.mean(np.square(np.asarray(rows)), axis=0))] if rows else []

    return {"per_force": per_force, "threshold_n": threshold, "rms_error_nm": rms(errors_all),
            "rms_error_settled_nm": rms(errors_settled), "push_samples": len(errors_all), "refused_goals": bench.refused,
            "trials": trials_seen, "max_force_n": bench.policy.force.estimated_force_limit_n, "backend_faults": faults,
            "no_baseline": refused}


def suggested_limits(false_alarm_runs: list[dict[str, Any]]) -> list[float]:
    """Per joint, a limit with room over the largest |estimate| any false-alarm run saw: 1.5× it
    and at least 1 N·m over it, rounded up to 0.5 N·m."""
    peaks = np.max([row["peak_estimate_nm"] for row in false_alarm_runs], axis=0)
    return [math.ceil(2 * max(1.5 * p, p + 1.0)) / 2 for p in peaks]


def suggested_force_limit(false_alarm_runs: list[dict[str, Any]]) -> float:
    """A TCP force limit [N] for the estimate with room over the largest trusted estimate any
    false-alarm run saw: 1.5x it and at least 5 N over it, rounded up to 1 N."""
    peak = max(row["peak_tcp_force_n"] for row in false_alarm_runs)
    return float(math.ceil(max(1.5 * peak, peak + 5.0)))


def threshold_with(detection: dict[str, Any], limits: list[float], force_limit_n: float | None = None) -> dict[str, Any]:
    """The detection shares per force had the per-joint limits been `limits` and the TCP force
    limit `force_limit_n` (None: the policy's), from the estimates each push trial recorded: what
    those limits would catch."""
    force_limit = detection["max_force_n"] if force_limit_n is None else force_limit_n
    shares: dict[str, float] = {}
    for trial in detection["trials"]:
        caught = (any(p > lim for p, lim in zip(trial["joint_peak_nm"], limits, strict=True))
                  or trial["wrench_peak_n"] > force_limit)
        key = f"{trial['force_n']:g}"
        shares.setdefault(key, 0.0)
        shares[key] += caught / detection["per_force"][key]["trials"]
    threshold = next((float(f) for f, share in sorted(shares.items(), key=lambda item: float(item[0]))
                      if share >= DETECTED_SHARE), None)
    return {"limits_nm": limits, "force_limit_n": force_limit, "shares": shares, "threshold_n": threshold}


# ---------------------------------------------------------------------------------------- 3
async def false_alarms(motions: int, payload_kg: float, rng: np.random.Generator,
                       section: dict[str, Any] | None = None, backend: str = "mujoco") -> dict[str, Any]:
    bench = await open_bench(backend, payload_kg, [], rng, section)
    violations: list[dict[str, Any]] = []
    peaks = np.zeros(len(bench.names))
    per_motion: list[np.ndarray] = []  # each motion's peak |estimate| per joint
    peak_force_n = 0.0  # the largest trusted TCP force estimate (held against the estimate's force limit)
    gaps_ms: list[float] = []  # each motion's longest interval between the joint states the monitor read
    faults = refused = 0
    try:
        while len(per_motion) < motions and faults + refused < motions:  # `motions` ran, unless most could not
            try:
                run = await bench.execute(await bench.random_motion(), stop_on_violation=False)
            except BackendError:
                faults += 1
                bench = await reopened(bench, backend, payload_kg, [], rng, section)
                continue
            if run.refused:  # the Guard would refuse to start it (NO_WRENCH): a stop for nothing, counted
                refused += 1
                violations.append({"kind": f"no_baseline ({run.violation.kind})", "detail": run.violation.detail})
                continue
            stamps = np.unique(run.state_stamps)
            gaps_ms.append(float(np.max(np.diff(stamps))) * 1e3 if len(stamps) > 1 else math.nan)
            if run.violation is not None:
                violations.append({"kind": run.violation.kind, "detail": run.violation.detail,
                                   "longest_gap_ms": gaps_ms[-1]})
            if run.peaks is not None:
                peaks = np.maximum(peaks, run.peaks)
                per_motion.append(np.asarray(run.peaks, dtype=float))
            forces = [sample[3] for sample in run.samples if not math.isnan(sample[3])]
            peak_force_n = max([peak_force_n, *forces])
    finally:
        await bench.cell.close()
    limits = bench.policy.force.joint_torques.per_joint("max_external_torque_nm", bench.names)
    kinds = [v["kind"] for v in violations]
    return {"motions": len(per_motion), "backend_faults": faults, "no_baseline": refused, "payload_kg": payload_kg,
            "violations": len(violations), "examples": violations[:5],
            "violations_by_kind": {k: kinds.count(k) for k in sorted(set(kinds))},
            "longest_gap_ms": percentiles([g for g in gaps_ms if math.isfinite(g)], (50, 99)),
            "peak_estimate_nm": [float(p) for p in peaks],
            "peak_estimate_p99_nm": [float(p) for p in np.percentile(per_motion, 99, axis=0)] if per_motion else [],
            "peak_estimate_p50_nm": [float(p) for p in np.percentile(per_motion, 50, axis=0)] if per_motion else [],
            "limits_nm": [float(v) for v in limits], "peak_tcp_force_n": peak_force_n,
            "max_force_n": bench.policy.force.estimated_force_limit_n, "refused_goals": bench.refused}


def bench_contact(quick: bool = False, limits_file: str | None = None, backend: str = "mujoco") -> dict[str, Any]:
    """Every figure `backend`'s cell gives (a key of `CELLS`), from one run (`quick`: a handful of
    trials each, to see it work; `limits_file`: the `force.joint_torques` section calibrate-contact
    wrote, else the bundled one)."""
    import anyio

    if backend not in CELLS:
        raise ValueError(f"no contact bench cell {backend!r}; choose from {', '.join(CELLS)}")
    section = joint_torques_section(limits_file)
    figures = CELLS[backend].figures

    latency_trials, detect_trials, motions = (3, 3, 10) if quick else (20, 20, 200)
    forces = (10.0, 30.0) if quick else FORCES_N

    async def main() -> dict[str, Any]:
        rng = np.random.default_rng(SEED)
        out: dict[str, Any] = {"quick": quick, "seed": SEED, "limits_file": limits_file, "backend": backend,
                               "cell": CELLS[backend].title, "switch_interval_s": sys.getswitchinterval()}
        started = time.monotonic()
        out["latency"] = await stop_latency(latency_trials, rng, section) if "latency" in figures else None
        out["detection"] = await detection(forces, detect_trials, rng, section, backend)
        out["false_alarms"] = [await false_alarms(motions, 0.0, rng, section, backend),
                               await false_alarms(motions, PAYLOAD_KG, rng, section, backend)]
        limits = suggested_limits(out["false_alarms"])
        out["with_suggested_limits"] = threshold_with(out["detection"], limits,
                                                      suggested_force_limit(out["false_alarms"]))
        out["wall_s"] = time.monotonic() - started
        return out

    # the interpreter as `armwarden serve` runs it: the servo, physics and emulator threads share one
    # interpreter lock with the monitor, and how long each waits for it shapes the samples measured
    from armwarden.daemon.startup import SWITCH_INTERVAL_S, freeze_long_lived_objects

    before = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    freeze_long_lived_objects()
    try:
        return anyio.run(main)
    finally:
        sys.setswitchinterval(before)


def report_contact(r: dict[str, Any]) -> None:
    def fmt(values: list[float]) -> str:
        return " / ".join(f"{v:.2f}" for v in values)

    section = r.get("limits_file") or "the bundled policy's"
    cell = r.get("cell", MujocoCell.title)
    print(f"\n== contact from joint torques ({cell}, speedup 1, force.source: joint_torques, {section} limits)")
    latency = r["latency"]
    if latency is None:
        print("stop latency into a box the policy does not know: not measured here (this simulation has no "
              "obstacles; the figure is the MuJoCo bench's)")
    else:
        ms, force, ft = latency["latency_ms"], latency["peak_contact_force_n"], latency["peak_hand_ft_n"]
        print(f"stop latency, contact onset -> e-stop commanded: p50 {ms['p50']:.1f} ms, p95 {ms['p95']:.1f} ms, "
              f"max {ms['max']:.1f} ms over {ms['n']} of {latency['trials']} trials (target p95 <= 20 ms: "
              f"{'met' if ms['p95'] <= 20 else 'MISSED'}); not stopped {latency['not_stopped']}; "
              f"lost to a backend fault {latency.get('backend_faults', 0)}, to no usable baseline "
              f"{latency.get('no_baseline', 0)}; by {latency['kinds']}")
        print(f"peak contact force (MuJoCo's robot-box contact forces) per trial: p50 {force['p50']:.1f} N, "
              f"max {force['max']:.1f} N; the hand's F/T reading (braking inertia included): p50 {ft['p50']:.1f} N, "
              f"max {ft['max']:.1f} N")
    detection = r["detection"]
    for f, row in detection["per_force"].items():
        print(f"  TCP push {f:>5} N for {PUSH_S:g} s mid-motion: detected {row['detected']}/{row['trials']} "
              f"({row['share']:.0%}); violations before the push {row['violations_before_push']}")
    threshold = detection["threshold_n"]
    goal = (f"goal <= 15 N: {'met' if threshold is not None and threshold <= 15 else 'MISSED'}"
            if r.get("backend", "mujoco") == "mujoco" else "the issue sets its 15 N goal for the FR3 in MuJoCo")
    print(f"detection threshold (>= {DETECTED_SHARE:.0%} detected): "
          f"{'none of the forces' if threshold is None else f'{threshold:g} N'} ({goal})")
    print(f"RMS error estimate - true external torque per joint during pushes [N·m]: {fmt(detection['rms_error_nm'])}"
          f"; settled ({SETTLED_AFTER_S * 1e3:g} ms in): {fmt(detection['rms_error_settled_nm'])} "
          f"({detection['push_samples']} samples; trials lost to a backend fault {detection.get('backend_faults', 0)}, "
          f"to no usable baseline {detection.get('no_baseline', 0)})")
    for row in r["false_alarms"]:
        margin = [limit - peak for limit, peak in zip(row["limits_nm"], row["peak_estimate_nm"], strict=True)]
        print(f"false alarms, payload {row['payload_kg']:g} kg: {row['violations']} in {row['motions']} motions "
              f"(besides, {row.get('backend_faults', 0)} lost to a backend fault; of the false alarms "
              f"{row.get('no_baseline', 0)} refused to start for want of a usable baseline) "
              f"(target 0: {'met' if row['violations'] == 0 else 'MISSED'}); peak |estimate| per joint "
              f"{fmt(row['peak_estimate_nm'])} N·m (per motion p50 {fmt(row['peak_estimate_p50_nm'])}, p99 "
              f"{fmt(row['peak_estimate_p99_nm'])}), margin to the limits {fmt(margin)} N·m; peak trusted TCP "
              f"force estimate {row['peak_tcp_force_n']:.1f} N (limit {row['max_force_n']:g} N)")
        if row["violations"]:
            print(f"    by kind: {row['violations_by_kind']} (wrench_stale / wrench_invalid: the joint-state stream "
                  "stalled, a lost reading the Guard fails closed on; joint_torque_limit / force_limit / torque_limit: "
                  "an estimate over a limit)")
        gaps = row.get("longest_gap_ms")
        if gaps is not None and gaps["n"]:
            print(f"    longest interval between the joint states the monitor read, per motion: p50 {gaps['p50']:.1f} ms, "
                  f"p99 {gaps['p99']:.1f} ms, max {gaps['max']:.1f} ms")
        for example in row["examples"]:
            gap = example.get("longest_gap_ms")
            print(f"    {example['kind']}: {example['detail']}"
                  + ("" if gap is None else f" (that motion's longest interval {gap:.1f} ms)"))
    suggested = r["with_suggested_limits"]
    shares = ", ".join(f"{f} N {share:.0%}" for f, share in suggested["shares"].items())
    at = suggested["threshold_n"]
    print(f"limits the false-alarm margins support (1.5x the peak, >= 1 N·m over it): {fmt(suggested['limits_nm'])} N·m, "
          f"TCP force {suggested.get('force_limit_n', float('nan')):g} N (1.5x the peak estimate, >= 5 N over it); "
          f"with them the same pushes are detected: {shares}; threshold {'none of the forces' if at is None else f'{at:g} N'}")
    print(f"wall time {r['wall_s']:.0f} s" + (" (quick)" if r["quick"] else ""))
