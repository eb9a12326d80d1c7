"""An in-memory ArmWarden for end-to-end tests through the official MCP SDK client.

`ArmHarness` builds the real Guard and server (`armwarden.assembly.build_guard`, as the daemon
does) on a backend — the fake by default, the tiny example backend ("minimal"), the MuJoCo
simulation ("mujoco", 4× real time), emulated CAN actuators ("can", examples/can_sim.yaml) or
ROS 2 ("ros2", examples/ros2_fr3.yaml against the fake FR3 cell `tests_ros.cell.Cell`, started
in this process for each harness) — wrapped in a `CountingBackend` that counts every actuation
command that reaches it: the proof that a refusal moved nothing. `ArmHarness.motions_below`
counts it once more one layer further down (CAN motion frames, goals at the cell's action
server). Tests talk to it only through `mcp.Client`, in either protocol mode.

Which backends the BACKENDS-parametrised tests (the scenario suite among them) run on:
`ARMWARDEN_HARNESS_BACKENDS`, a comma-separated subset of `KNOWN_BACKENDS`; unset, every backend
but "ros2" (which needs rclpy and the built interfaces, so the plain `pytest tests` run never
imports ROS). scripts/test.sh's ROS run sets it to "ros2" in the ROS venv, with a random
ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
from mcp import Client

from armwarden.assembly import build_backend, build_guard
from armwarden.audit import OS_DISK, AuditLog, Disk, verify_file
from armwarden.backends.base import Backend
from armwarden.backends.counting import CountingBackend
from armwarden.backends.fake import Config as FakeConfig
from armwarden.backends.fake.backend import FakeBackend
from armwarden.core.errors import BackendError
from armwarden.daemon.startup import SWITCH_INTERVAL_S, freeze_long_lived_objects
from armwarden.guard import Guard
from armwarden.policy import Policy, apply_overrides, bundled_policy, load_policy, parse_policy
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from armwarden.robot import build_robot
from armwarden.server.app import ArmWardenServer
from tests.backends.minimal_backend import MinimalBackend
from tests.helpers import text_of

MODES = ("legacy", "2026-07-28")
HOME_TCP_X = 0.3069  # the bundled policy's home pose puts the TCP at (0.3069, 0, 0.4869) m
#: every backend the harness can build
KNOWN_BACKENDS = ("fake", "minimal", "mujoco", "can", "ros2")
#: the environment variable that chooses the backends of `BACKENDS` (module docstring)
BACKENDS_ENV = "ARMWARDEN_HARNESS_BACKENDS"


def _chosen_backends() -> tuple[str, ...]:
    """`BACKENDS_ENV` as a tuple of known names; unset or empty: every backend but ros2."""
    chosen = tuple(name.strip() for name in os.environ.get(BACKENDS_ENV, "").split(",") if name.strip())
    unknown = sorted(set(chosen) - set(KNOWN_BACKENDS))
    if unknown:
        raise ValueError(f"{BACKENDS_ENV} names unknown harness backends {unknown}; known: {', '.join(KNOWN_BACKENDS)}")
    return chosen or tuple(name for name in KNOWN_BACKENDS if name != "ros2")


#: backends a scenario can run on: parametrise with `@pytest.mark.parametrize("backend", BACKENDS)`
BACKENDS = _chosen_backends()
#: simulated time per wall time of the harness's simulated backends (scenarios take seconds);
#: the ROS cell interpolates goals in real time
SPEEDUP = {"fake": 10.0, "minimal": 10.0, "mujoco": 4.0, "can": 2.0, "ros2": 1.0}
#: backends whose simulation runs against the wall clock: a long garbage collection (the test
#: process's heap is large) stalls their physics and makes the wrench stale, as it would in a
#: daemon that did not freeze its long-lived objects
REAL_TIME = ("mujoco", "can", "ros2")
#: the emulated RobStride arm the "can" harness backend drives (on a virtual bus of its own)
CAN_SIM = Path(__file__).resolve().parents[2] / "examples" / "can_sim.yaml"
#: the ROS 2 wiring of a ros2_control FR3, whose names the fake cell's defaults mirror
ROS2_FR3 = Path(__file__).resolve().parents[2] / "examples" / "ros2_fr3.yaml"

ElicitationCallback = Callable[[Any, types.ElicitRequestParams], Awaitable[types.ElicitResult]]


def approve(operator: str = "test-operator") -> ElicitationCallback:
    async def callback(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        callback.prompts.append(params.message)  # type: ignore[attr-defined]
        return types.ElicitResult(action="accept", content={"approve": True, "operator": operator})

    callback.prompts = []  # type: ignore[attr-defined]
    return callback


def answer(action: str, content: dict | None = None) -> ElicitationCallback:
    async def callback(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        callback.prompts.append(params.message)  # type: ignore[attr-defined]
        return types.ElicitResult(action=action, content=content)

    callback.prompts = []  # type: ignore[attr-defined]
    return callback


class MotionStarted:
    """A progress callback for `call_tool`; `event` is set at the first progress above 0."""

    def __init__(self) -> None:
        self.event = anyio.Event()

    async def __call__(self, progress: float, total: float | None, message: str | None) -> None:
        if progress > 0:
            self.event.set()


async def plan_down(client: Client, z: float, *, status: str | None = None) -> dict[str, Any]:
    """`plan_to_pose` straight down (or up) from the home TCP to height `z` m; the plan summary.
    The call must not be refused; with `status`, the summary must have that status too."""
    result = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": z}})
    assert not result.is_error, text_of(result)
    summary = result.structured_content
    if status is not None:
        assert summary["status"] == status, summary
    return summary


async def wait_until(predicate: Callable[[], bool], timeout_s: float = 5.0, what: str = "condition") -> None:
    """Poll `predicate` every 5 ms until it holds; fail naming `what` after `timeout_s`. (The state
    polled, e.g. `guard.motion_status()`, is moved by the backend's thread: there is no event to await.)"""
    deadline = anyio.current_time() + timeout_s
    while not predicate():
        assert anyio.current_time() < deadline, f"{what}: not reached within {timeout_s} s"
        await anyio.sleep(0.005)


def policy_with(**overrides: Any) -> Policy:
    """The bundled FR3 policy with dotted-path overrides, e.g. `policy_with(**{"approval.mode": "always"})`."""
    import yaml

    document = yaml.safe_load(bundled_policy("fr3").read_text())
    return parse_policy(apply_overrides(document, overrides), source="test")


class ArmHarness:
    def __init__(self, guard: Guard, server: ArmWardenServer, backend: CountingBackend, inner: Backend,
                 audit: AuditLog, audit_path: Path, cell: Any = None) -> None:
        self.guard, self.server, self.backend, self.inner = guard, server, backend, inner
        self.audit, self.audit_path = audit, audit_path
        #: the fake ROS cell (`tests_ros.cell.Cell`) behind the ros2 backend; None on the others
        self.cell = cell

    @property
    def fake(self) -> FakeBackend:
        """The fake backend behind the counter (for fault injection); only on the fake."""
        assert isinstance(self.inner, FakeBackend), f"this scenario runs on the {self.inner.name} backend, not the fake"
        return self.inner

    @property
    def actuations(self) -> list[str]:
        return self.backend.actuations

    @property
    def motions_below(self) -> int | None:
        """Motion that reached the layer below the backend, counted there: on CAN, executions that
        put trajectory-following command frames on the bus (not the hold/damping stream); on ROS 2,
        trajectory goals received by the cell's action server (accepted or not). None on a backend
        with nothing below it (fake, minimal, MuJoCo)."""
        if self.cell is not None:
            return self.cell.counters().goals_received
        return getattr(self.inner, "moving_executions", None)

    @contextlib.asynccontextmanager
    async def client(self, mode: str = "legacy", elicitation: ElicitationCallback | None = None) -> AsyncIterator[Client]:
        async with Client(self.server.mcp, mode=mode, elicitation_callback=elicitation) as client:
            yield client


def _backend(name: str, policy: Policy, options: dict[str, Any]) -> Backend:
    """The backend `name` for `policy`. Fake options that are `Config` fields configure it; the
    rest are its fault-injection attributes (`fail_stop=True`, `stall_wrench_s=0.3`, ...)."""
    robot = build_robot(policy)
    if name == "minimal":
        if options:
            raise TypeError(f"the minimal backend takes no options, got {sorted(options)}")
        return MinimalBackend(robot.joint_names, policy.robot.home_joint_positions,
                              start_tolerance_rad=policy.motion.start_tolerance_rad, speedup=SPEEDUP[name])
    if name == "mujoco":
        return build_backend("mujoco", policy, robot=robot, config={"speedup": SPEEDUP[name]} | options)
    if name == "can":
        import uuid

        import yaml

        document = yaml.safe_load(CAN_SIM.read_text())
        document["bus"]["channel"] = f"armwarden-harness-{uuid.uuid4().hex}"  # virtual buses of one name share frames
        document["simulate"]["speedup"] = SPEEDUP[name]
        # the test process stalls its threads far longer than a daemon (planning, a large heap, 2 cores
        # shared with other suites): watch for silence on a scale those stalls do not reach
        document |= {"rx_timeout_s": 1.0, "can_timeout_s": 2.0}
        return build_backend("can", policy, robot=robot, config=document | options)
    if name == "ros2":
        import yaml

        document = yaml.safe_load(ROS2_FR3.read_text())
        # the cell publishes from a thread of the test process, which stalls far longer than a daemon
        # (planning, a large heap, 2 cores shared with other suites): ages on a scale those stalls do not reach
        document["joint_states"]["max_age_s"] = 1.0
        document["wrench"]["max_age_s"] = MAX_WRENCH_TIMEOUT_S
        return build_backend("ros2", policy, robot=robot, config=document | options)
    if name != "fake":
        raise ValueError(f"unknown harness backend {name!r}; choose one of {KNOWN_BACKENDS}")
    config = {key: value for key, value in options.items() if key in FakeConfig.model_fields}
    fake = build_backend("fake", policy, robot=robot, config={"speedup": SPEEDUP[name]} | config)
    assert isinstance(fake, FakeBackend)
    for key, value in options.items():
        if key not in config:
            if not hasattr(fake, key):
                raise TypeError(f"the fake backend has no option or attribute {key!r}")
            setattr(fake, key, value)
    return fake


def _policy_for(backend: str) -> Policy:
    """The bundled policy, adapted to what `backend` has: without a wrench estimate, execution
    runs without force enforcement (the gripper and camera tools are simply not registered)."""
    if backend in ("minimal", "can"):
        return policy_with(**{"force.require_wrench": False})
    return load_policy(bundled_policy("fr3"))


def _ros_cell(stack: contextlib.AsyncExitStack) -> Any:
    """The fake FR3 cell of real rclpy endpoints, running until `stack` closes. Imported here: the
    plain `pytest tests` run has no rclpy."""
    from tests_ros.cell import Cell

    return stack.enter_context(Cell())


def _for_an_in_process_cell(policy: Policy) -> Policy:
    """`policy` with the longest wrench timeout a policy may set: the cell (the ROS 2 cell's
    publishers, the MuJoCo physics) runs on threads of the test process, which stall far longer
    than a cell of its own (measured here: gaps of 0.1–0.24 s between wrench messages while a
    scenario executes on a loaded 2-core machine). Wrench staleness has tests of its own."""
    force = policy.force.model_copy(update={"wrench_timeout_s": MAX_WRENCH_TIMEOUT_S})
    return policy.model_copy(update={"force": force})


async def _first_wrench(backend: Backend, timeout_s: float = 15.0) -> None:
    """Wait until `backend` has a fresh wrench (DDS discovery of a best-effort topic takes a while)."""
    with anyio.fail_after(timeout_s):
        while True:
            with contextlib.suppress(BackendError):  # "no wrench received yet" until the first message
                if await backend.read_wrench() is not None:
                    return
            await anyio.sleep(0.02)


@contextlib.asynccontextmanager
async def arm_harness(tmp_path: Path, policy: Policy | None = None, *, backend: str = "fake",
                      audit_disk: Disk = OS_DISK, **fake_options: Any) -> AsyncIterator[ArmHarness]:
    """The harness on `backend`; `audit_disk` is the audit log's file system (a test's
    `tests.fulldisk.SmallDisk` to fill it up)."""
    policy = policy or _policy_for(backend)
    if backend in REAL_TIME:
        policy = _for_an_in_process_cell(policy)
    inner = _backend(backend, policy, fake_options)
    counting = CountingBackend(inner)
    audit_path = tmp_path / "audit.jsonl"
    audit = AuditLog(audit_path, disk=audit_disk)
    threshold, switch_interval = gc.get_threshold(), sys.getswitchinterval()
    if backend in REAL_TIME:  # as the daemon does: the test process's large heap must not stall the clock
        freeze_long_lived_objects()  # before the physics starts: the collection itself takes ~100 ms
    if backend in REAL_TIME:  # as the daemon does: the cell's and the backend's threads take turns on the interpreter lock
        sys.setswitchinterval(SWITCH_INTERVAL_S)
    async with contextlib.AsyncExitStack() as stack:
        cell = _ros_cell(stack) if backend == "ros2" else None
        await inner.open()
        stack.push_async_callback(inner.close)  # closed before the cell (the stack unwinds in reverse)
        if cell is not None:  # open() waits for the joint state; a scenario may execute before the first wrench
            await _first_wrench(inner)
        guard = build_guard(policy, counting, audit)
        server = ArmWardenServer(guard)
        try:
            yield ArmHarness(guard, server, counting, inner, audit, audit_path, cell)
        finally:
            await stack.aclose()
            audit.close()
            if backend in REAL_TIME:
                gc.unfreeze()
                gc.set_threshold(*threshold)
            sys.setswitchinterval(switch_interval)
    report = verify_file(audit_path)  # whatever the scenario did, the chain it left must verify
    assert report.ok, f"audit chain broken at line {report.first_bad_line}: {report.reason}"
