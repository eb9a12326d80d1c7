#!/usr/bin/env python3
"""Safety evaluation: unsafe requests must be refused with zero actuation commands reaching the
backend; random safe moves must all execute, and after each the TCP is re-checked independently.

    python scripts/eval_safety.py [--moves 40] [--seed 1]

Runs the real Guard and MCP server in memory on the fake backend (the only backend this issue
set provides), wrapped in `CountingBackend`, through the official SDK client. Prints one line per
scenario and a closing "N passed, M failed" line; exits 1 if anything failed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
import numpy as np
import yaml
from mcp import Client

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from armwarden.assembly import build_backend, build_guard
from armwarden.audit import AuditLog, verify_file
from armwarden.backends.counting import CountingBackend
from armwarden.policy import Policy, apply_overrides, bundled_policy, parse_policy
from armwarden.preflight import load_runtime_model
from armwarden.server.app import ArmWardenServer

READY = [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]


def _policy(**overrides: Any) -> Policy:
    document = yaml.safe_load(bundled_policy("fr3").read_text())
    unlimited = {"rate_limits": {"global_per_minute": 100000, "default_per_minute": 100000, "per_tool": {}}}
    return parse_policy(apply_overrides(document, unlimited | overrides), source="eval")


async def _approve(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
    return types.ElicitResult(action="accept", content={"approve": True, "operator": "eval"})


def _joints(**changes: float) -> list[float]:
    q = list(READY)
    for name, delta in changes.items():
        q[int(name[1:]) - 1] += delta
    return q


async def _plan_then_execute(client: Client, tool: str, args: dict) -> Any:
    plan = await client.call_tool(tool, args | {"preview": False})
    if plan.is_error or plan.structured_content.get("plan_id") is None:
        return plan
    return await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})


async def _replay(client: Client) -> Any:
    plan = await client.call_tool("plan_to_joints", {"joint_positions": _joints(j1=0.1), "preview": False})
    plan_id = plan.structured_content["plan_id"]
    await client.call_tool("execute_plan", {"plan_id": plan_id})
    return await client.call_tool("execute_plan", {"plan_id": plan_id})


async def _while_estopped(client: Client) -> Any:
    await client.call_tool("estop", {"reason": "eval"})
    return await _plan_then_execute(client, "plan_to_joints", {"joint_positions": _joints(j1=0.1)})


Scenario = tuple[str, Policy | None, bool, Callable[[Client], Awaitable[Any]], int]
ELBOW = (np.array([[np.cos(-1.2), -np.sin(-1.2), 0], [np.sin(-1.2), np.cos(-1.2), 0], [0, 0, 1]]) @ [-0.165, 0, 0.615]).tolist()

# (name, policy or None for the default, client can elicit, action, actuations allowed before the refusal)
UNSAFE: list[Scenario] = [
    ("joint target past a limit", None, True,
     lambda c: _plan_then_execute(c, "plan_to_joints", {"joint_positions": _joints(j4=2.3)}), 0),
    ("TCP below the table", None, True,
     lambda c: _plan_then_execute(c, "plan_to_pose", {"position": {"x": 0.45, "y": 0.0, "z": 0.0}}), 0),
    ("pose inside the monitor keep-out zone", None, True,
     lambda c: _plan_then_execute(c, "plan_to_pose", {"position": {"x": 0.55, "y": 0.5, "z": 0.3}}), 0),
    ("Cartesian path into a keep-out zone", None, True,
     lambda c: _plan_then_execute(c, "plan_cartesian_path", {"waypoints": [{"position": {"x": 0.55, "y": 0.45, "z": 0.35}}]}), 0),
    ("elbow through a keep-out zone (TCP clear)",
     _policy(**{"workspace.keep_out": [{"name": "lamp", "min": [x - 0.03 for x in ELBOW], "max": [x + 0.03 for x in ELBOW]}]}),
     True, lambda c: _plan_then_execute(c, "plan_to_joints", {"joint_positions": _joints(j1=-1.5)}), 0),
    ("joint step over the hard cap", None, True,
     lambda c: _plan_then_execute(c, "plan_to_joints", {"joint_positions": _joints(j7=-1.6)}), 0),
    ("Cartesian path over the length cap", None, True,
     lambda c: _plan_then_execute(c, "plan_cartesian_path", {"waypoints": [
         {"position": {"x": 0.45, "y": 0.25, "z": 0.3}}, {"position": {"x": 0.45, "y": -0.25, "z": 0.3}}]}), 0),
    ("unknown plan id", None, True, lambda c: c.call_tool("execute_plan", {"plan_id": "plan_forged"}), 0),
    ("replayed plan", None, True, _replay, 1),
    ("forged approval from a client without elicitation", _policy(**{"approval.mode": "always"}), False,
     lambda c: _plan_then_execute(c, "plan_to_joints", {"joint_positions": _joints(j1=0.1)}), 0),
    ("motion while e-stopped", None, True, _while_estopped, 0),
    ("NaN joint target", None, True,
     lambda c: c.call_tool("plan_to_joints", {"joint_positions": [float("nan")] * 7}), 0),
    ("grasp force over the cap", None, True,
     lambda c: c.call_tool("gripper_grasp", {"width_m": 0.02, "force_n": 500.0}), 0),
    ("controller outside the allowlist", None, True,
     lambda c: c.call_tool("switch_controllers", {"activate": ["rogue_controller"]}), 0),
    ("collision thresholds over the force cap", None, True,
     lambda c: c.call_tool("set_collision_thresholds", {"force_n": 500.0, "torque_nm": 5.0}), 0),
    ("camera outside the allowlist", None, True, lambda c: c.call_tool("camera_snapshot", {"camera": "ceiling"}), 0),
]


class Evaluation:
    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.passed = 0
        self.failed = 0

    def report(self, name: str, ok: bool, detail: str) -> None:
        self.passed += ok
        self.failed += not ok
        print(f"{'PASS' if ok else 'FAIL'}  {name}: {detail}")

    async def arm(self, policy: Policy | None, tag: str):
        policy = policy or _policy()
        fake = build_backend("fake", policy, config={"speedup": 50.0})
        backend = CountingBackend(fake)
        audit = AuditLog(self.directory / f"{tag}.jsonl")
        await fake.open()
        return fake, backend, audit, ArmWardenServer(build_guard(policy, backend, audit))

    async def unsafe(self) -> None:
        for index, (name, policy, elicits, action, allowed) in enumerate(UNSAFE):
            fake, backend, audit, server = await self.arm(policy, f"unsafe-{index}")
            try:
                async with Client(server.mcp, elicitation_callback=_approve if elicits else None) as client:
                    result = await action(client)
                refused = bool(result.is_error) or (result.structured_content or {}).get("status") == "rejected"
                moved = len(backend.actuations) - allowed
                text = (result.content[0].text if result.content else "").replace("\n", " ")
                self.report(name, refused and moved == 0, f"refused={refused}, extra actuations={moved}: {text[:110]}")
            finally:
                await fake.close()
                audit.close()
            chain = verify_file(self.directory / f"unsafe-{index}.jsonl")
            if not chain.ok:
                self.report(f"{name} (audit chain)", False, chain.reason or "broken")

    async def safe_moves(self, count: int, seed: int) -> None:
        rng = np.random.default_rng(seed)
        fake, _, audit, server = await self.arm(None, "safe")
        checker = load_runtime_model(_policy())  # an independent model instance for the re-check
        limits = checker.envelope.limits
        executed = skipped = 0
        try:
            async with Client(server.mcp, elicitation_callback=_approve) as client:
                for i in range(count):
                    state = (await client.call_tool("get_robot_state", {})).structured_content
                    goal = np.clip(np.array(state["joint_positions"]) + rng.uniform(-0.25, 0.25, 7),
                                   checker.robot.lower + 0.1, checker.robot.upper - 0.1)
                    plan = await client.call_tool("plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
                    summary = plan.structured_content
                    if summary["status"] == "rejected":
                        skipped += 1
                        continue
                    done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
                    ok = not done.is_error and done.structured_content["status"] == "succeeded"
                    q = (await fake.read_joint_state()).positions
                    tcp = checker.robot.tcp_pose(q).position
                    inside = bool(np.all(tcp >= limits.workspace.lo) and np.all(tcp <= limits.workspace.hi))
                    clear = all(not (np.all(tcp >= z.lo) and np.all(tcp <= z.hi)) for z in limits.keep_out)
                    reached = np.allclose(q, goal, atol=1e-6)
                    executed += ok
                    if not (ok and inside and clear and reached):
                        self.report(f"safe move {i}", False, f"executed={ok} reached={reached} tcp={tcp.round(3)}")
            self.report("random safe moves", executed + skipped == count and executed > 0,
                        f"{executed} executed, {skipped} rejected by the envelope, TCP re-checked after each")
        finally:
            await fake.close()
            audit.close()


async def main_async(moves: int, seed: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        evaluation = Evaluation(Path(tmp))
        await evaluation.unsafe()
        await evaluation.safe_moves(moves, seed)
    print(f"{evaluation.passed} passed, {evaluation.failed} failed")
    return 0 if evaluation.failed == 0 else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--moves", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    import logging

    logging.basicConfig(level=logging.WARNING)
    return anyio.run(main_async, args.moves, args.seed)


if __name__ == "__main__":
    sys.exit(main())
