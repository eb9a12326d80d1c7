"""An in-memory ArmWarden for end-to-end tests through the official MCP SDK client.

`ArmHarness` builds the real Guard and server on the fake backend, wrapped in a
`CountingBackend` (armwarden.backends.counting) that counts every actuation command that reaches it — the proof that a
refusal moved nothing. Tests talk to it only through `mcp.Client`, in either protocol mode.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
from mcp import Client

from armwarden.backends.counting import CountingBackend
from armwarden.backends.fake import FakeBackend
from armwarden.policy import bundled_policy
from armwarden.guard import Guard
from armwarden.policy import Policy, apply_overrides, load_policy, parse_policy
from armwarden.preflight import load_runtime_model
from armwarden.robot import build_robot
from armwarden.safety.audit import AuditLog, verify_file
from armwarden.server.app import ArmWardenServer

MODES = ("legacy", "2026-07-28")

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


def policy_with(**overrides: Any) -> Policy:
    """The bundled FR3 policy with dotted-path overrides, e.g. `policy_with(**{"approval.mode": "always"})`."""
    import yaml

    document = yaml.safe_load(bundled_policy("fr3").read_text())
    return parse_policy(apply_overrides(document, overrides), source="test")


class ArmHarness:
    def __init__(self, guard: Guard, server: ArmWardenServer, backend: CountingBackend, fake: FakeBackend,
                 audit: AuditLog, audit_path: Path) -> None:
        self.guard, self.server, self.backend, self.fake = guard, server, backend, fake
        self.audit, self.audit_path = audit, audit_path

    @property
    def actuations(self) -> list[str]:
        return self.backend.actuations

    @contextlib.asynccontextmanager
    async def client(self, mode: str = "legacy", elicitation: ElicitationCallback | None = None) -> AsyncIterator[Client]:
        async with Client(self.server.mcp, mode=mode, elicitation_callback=elicitation) as client:
            yield client


@contextlib.asynccontextmanager
async def arm_harness(tmp_path: Path, policy: Policy | None = None, **fake_options: Any) -> AsyncIterator[ArmHarness]:
    policy = policy or load_policy(bundled_policy("fr3"))
    runtime = load_runtime_model(policy)
    robot = build_robot(policy)
    options = {"speedup": 10.0} | fake_options
    fake = FakeBackend(robot=robot, home=list(policy.robot.home_joint_positions), **options)
    backend = CountingBackend(fake)
    audit_path = tmp_path / "audit.jsonl"
    audit = AuditLog(audit_path)
    await fake.open()
    guard = Guard(policy, runtime, robot, backend, audit=audit)  # type: ignore[arg-type]
    server = ArmWardenServer(guard)
    try:
        yield ArmHarness(guard, server, backend, fake, audit, audit_path)
    finally:
        await fake.close()
        audit.close()
    report = verify_file(audit_path)  # whatever the scenario did, the chain it left must verify
    assert report.ok, f"audit chain broken at line {report.first_bad_line}: {report.reason}"
