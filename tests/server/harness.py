"""An in-memory ArmWarden for end-to-end tests through the official MCP SDK client.

`ArmHarness` builds the real Guard and server (`armwarden.assembly.build_guard`, as the daemon
does) on a backend — the fake by default, the tiny example backend ("minimal"), the MuJoCo
simulation ("mujoco", 4× real time), emulated CAN actuators ("can", examples/can_sim.yaml) or
ROS 2 ("ros2", examples/ros2_fr3.yaml against the fake FR3 cell `tests_ros.cell.Cell`, started
in this process for each harness) — built by that backend's `build_for_tests` (its package's
`testing` module, found through the backend registry; the minimal one's is in
tests/backends/minimal_backend.py) and wrapped in a `CountingBackend` that counts every actuation
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
import importlib
import importlib.util
import os
import sys
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
from mcp import Client

from armwarden.assembly import build_guard
from armwarden.audit import OS_DISK, AuditLog, Disk, verify_file
from armwarden.backends import registered_backends
from armwarden.backends.base import Backend
from armwarden.backends.counting import CountingBackend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.core.errors import BackendError
from armwarden.daemon.startup import SWITCH_INTERVAL_S, freeze_long_lived_objects
from armwarden.guard import Guard
from armwarden.policy import Policy, apply_overrides, bundled_policy, load_policy, parse_policy
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from armwarden.robot import build_robot
from armwarden.server.app import ArmWardenServer
from tests.helpers import text_of

MODES = ("legacy", "2026-07-28")
HOME_TCP_X = 0.3069  # the bundled policy's home pose puts the TCP at (0.3069, 0, 0.4869) m
#: the backends only the tests have (no registry names them): name -> the module of their `build_for_tests`
TEST_ONLY_BACKENDS = {"minimal": "tests.backends.minimal_backend"}
#: every backend the harness can build: the registry's (built-in or an entry point's, each with a
#: `testing` module beside it) and the test-only ones
KNOWN_BACKENDS = ("fake", *TEST_ONLY_BACKENDS, *(name for name in registered_backends() if name != "fake"))
#: the backends a run without `BACKENDS_ENV` uses: every built-in one but ros2
DEFAULT_BACKENDS = ("fake", "minimal", "mujoco", "can")
#: the environment variable that chooses the backends of `BACKENDS` (module docstring)
BACKENDS_ENV = "ARMWARDEN_HARNESS_BACKENDS"


def _chosen_backends() -> tuple[str, ...]:
    """`BACKENDS_ENV` as a tuple of known names; unset or empty: every backend but ros2."""
    chosen = tuple(name.strip() for name in os.environ.get(BACKENDS_ENV, "").split(",") if name.strip())
    unknown = sorted(set(chosen) - set(KNOWN_BACKENDS))
    if unknown:
        raise ValueError(f"{BACKENDS_ENV} names unknown harness backends {unknown}; known: {', '.join(KNOWN_BACKENDS)}")
    return chosen or DEFAULT_BACKENDS


#: backends a scenario can run on: parametrise with `@pytest.mark.parametrize("backend", BACKENDS)`
BACKENDS = _chosen_backends()
#: simulated time per wall time of the harness's simulated backends (scenarios take seconds);
#: the ROS cell interpolates goals in real time
SPEEDUP = {"fake": 10.0, "minimal": 10.0, "mujoco": 4.0, "can": 2.0, "ros2": 1.0}
#: backends whose simulation runs against the wall clock: a long garbage collection (the test
#: process's heap is large) stalls their physics and makes the wrench stale, as it would in a
#: daemon that did not freeze its long-lived objects
REAL_TIME = ("mujoco", "can", "ros2")

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

    def push(self, link: str, force_base: tuple[float, float, float]) -> None:
        """Push on the arm with `force_base` [N] (base frame) at the origin of `link`, from the next
        sample on until `release_push`: whatever simulates the arm pushes (the ROS cell, the CAN
        emulator, or the simulated backend itself)."""
        self._pusher().push(link, force_base)

    def release_push(self) -> None:
        self._pusher().release_push()

    def _pusher(self) -> Any:
        for candidate in (self.cell, getattr(self.inner, "emulator", None), self.inner):
            if candidate is not None and callable(getattr(candidate, "push", None)):
                return candidate
        raise AssertionError(f"nothing simulates a push on the {self.inner.name} backend")

    @contextlib.asynccontextmanager
    async def client(self, mode: str = "legacy", elicitation: ElicitationCallback | None = None) -> AsyncIterator[Client]:
        async with Client(self.server.mcp, mode=mode, elicitation_callback=elicitation) as client:
            yield client


def testing_module(name: str) -> str:
    """The module holding backend `name`'s `build_for_tests`: the `testing` module of the package
    its registered module is (or is in). Found without importing that backend (no rclpy, no
    python-can until one is built)."""
    if name in TEST_ONLY_BACKENDS:
        return TEST_ONLY_BACKENDS[name]
    backends = registered_backends()
    if name not in backends:
        raise ValueError(f"unknown harness backend {name!r}; choose one of {KNOWN_BACKENDS}")
    module = backends[name]
    spec = importlib.util.find_spec(module)  # imports the parent packages only
    package = module if spec is not None and spec.submodule_search_locations is not None else module.rpartition(".")[0]
    return f"{package}.testing"


def _backend(name: str, policy: Policy, options: dict[str, Any]) -> Backend:
    """The backend `name` for `policy`, built by its `build_for_tests` with the harness's speedup;
    `options` are what that function takes (the fake: `Config` fields and fault-injection
    attributes such as `fail_stop=True`, `stall_wrench_s=0.3`)."""
    testing = importlib.import_module(testing_module(name))
    return testing.build_for_tests(policy, build_robot(policy), speedup=SPEEDUP.get(name, 1.0), options=options)


def _policy_for(backend: str) -> Policy:
    """The bundled policy, adapted to what `backend` has: with neither a wrench estimate nor
    measured joint torques (the minimal backend; CAN, whose emulator's torques are not the arm's),
    execution runs without force enforcement (the gripper and camera tools are simply not registered)."""
    if backend in ("minimal", "can"):
        return policy_with(**{"force.require_wrench": False})
    return load_policy(bundled_policy("fr3"))


def _ros_cell(stack: contextlib.AsyncExitStack) -> Any:
    """The fake FR3 cell of real rclpy endpoints, running until `stack` closes. Imported here: the
    plain `pytest tests` run has no rclpy."""
    from tests_ros.cell import Cell

    return stack.enter_context(Cell())


def _stall_tolerant(policy: Policy) -> Policy:
    """`policy` with the longest wrench timeout a policy may set. The arm (the fake's servo thread,
    the ROS 2 cell's publishers, the MuJoCo physics) runs on threads of the test process, which
    stall far longer than an arm of its own (measured here: gaps of 0.1–0.24 s between wrench
    messages while a scenario executes on a loaded 2-core machine; a fake's wrench 0.1 s old failed
    a CI run's plain execution). Used for the default policy on every backend and for any policy
    on a real-time one; wrench staleness has tests of their own, which pass their policy."""
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
    if policy is None:  # a test of wrench staleness passes the policy (e.g. `policy_with()`) explicitly
        policy = _stall_tolerant(_policy_for(backend))
    elif backend in REAL_TIME:
        policy = _stall_tolerant(policy)
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
