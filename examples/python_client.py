#!/usr/bin/env python3
"""A minimal ArmWarden client with the official MCP Python SDK: plan, approve, execute.

By default it launches the daemon itself on stdio (the bundled FR3 policy on the fake backend,
so no hardware is needed); with --http it connects to a running daemon instead:

    python examples/python_client.py                         # stdio, asks you before moving
    python examples/python_client.py --yes                   # stdio, approves automatically
    armwarden tokens add tokens.json --role agent --name claude   # this client's token (printed once)
    armwarden serve --transport http --auth-tokens tokens.json &
    python examples/python_client.py --http http://127.0.0.1:8765/mcp --token aw_...

When the server needs a human's approval (a plan outside the soft envelope, an e-stop reset, ...)
it sends an elicitation request; this client prints the server's prompt and asks y/N on the
terminal. --yes answers "approve" without asking: only for scripted use against a simulator.

The motion is small on purpose: joint 7 (the wrist) turns by --delta radians from where it is.
"""

from __future__ import annotations

import argparse
import contextlib
import getpass
import os
import sys
from collections.abc import AsyncIterator
from typing import Any

import anyio
import mcp_types as types
from mcp import Client, StdioServerParameters


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--http", metavar="URL", help="connect to a running daemon, e.g. http://127.0.0.1:8765/mcp")
    parser.add_argument("--token", metavar="T", help="bearer token for --http (from `armwarden tokens add`)")
    parser.add_argument("--policy", help="policy for the stdio daemon (default: the bundled FR3 policy)")
    parser.add_argument("--backend", default="fake", help="backend of the stdio daemon: fake (default) or mujoco")
    parser.add_argument("--audit-log", default="armwarden-audit.jsonl", help="audit log of the stdio daemon")
    parser.add_argument("--yes", action="store_true", help="approve every prompt without asking (scripted use)")
    parser.add_argument("--delta", type=float, default=0.2, help="wrist rotation to plan [rad] (default 0.2)")
    parser.add_argument("--operator", default=None, help="name recorded with your approvals (default: your login)")
    return parser.parse_args(argv)


class TerminalApprover:
    """Shows the server's approval prompt and returns the human's answer."""

    def __init__(self, auto_approve: bool, operator: str) -> None:
        self.auto_approve = auto_approve
        self.operator = operator

    async def __call__(self, context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        print("\n" + "=" * 72)
        print(getattr(params, "message", "(the server sent no message)"))
        print("=" * 72)
        if self.auto_approve:
            print("--yes given: approving")
            approved = True
        else:
            answer = await anyio.to_thread.run_sync(lambda: input("Approve? [y/N] "))
            approved = answer.strip().lower() in ("y", "yes")
        if not approved:
            return types.ElicitResult(action="decline")
        return types.ElicitResult(action="accept", content={"approve": True, "operator": self.operator})


@contextlib.asynccontextmanager
async def connect(args: argparse.Namespace, approver: TerminalApprover) -> AsyncIterator[Client]:
    if args.http:
        import httpx2
        from mcp.client.streamable_http import streamable_http_client

        headers = {"Authorization": f"Bearer {args.token}"} if args.token else {}
        http = httpx2.AsyncClient(headers=headers)
        async with http, Client(streamable_http_client(args.http, http_client=http),
                                elicitation_callback=approver) as client:
            yield client
        return
    command = [sys.executable, "-m", "armwarden.cli", "serve", "--backend", args.backend, "--audit-log", args.audit_log,
               "--log-level", "WARNING"]
    if args.policy:
        command += ["--policy", args.policy]
    # the SDK gives the child a minimal environment; pass PYTHONPATH on for runs from a checkout
    env = {"PYTHONPATH": os.environ["PYTHONPATH"]} if os.environ.get("PYTHONPATH") else None
    server = StdioServerParameters(command=command[0], args=command[1:], env=env)
    async with Client(server, elicitation_callback=approver) as client:
        yield client


def text_of(result: types.CallToolResult) -> str:
    return " ".join(block.text for block in result.content if isinstance(block, types.TextContent))


class Refused(Exception):
    """The server refused a call (an `isError` result); the text says why."""


async def call(client: Client, tool: str, arguments: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
    result = await client.call_tool(tool, arguments, **kwargs)
    if result.is_error:
        raise Refused(f"{tool} was refused: {text_of(result)}")
    return result.structured_content or {}


async def main(args: argparse.Namespace) -> int:
    approver = TerminalApprover(args.yes, args.operator or getpass.getuser())
    async with connect(args, approver) as client:
        try:
            await session(client, args)
        except Refused as exc:  # handled inside the session so the SDK's task groups stay clean
            print(f"\n{exc}")
            return 1
    return 0


async def session(client: Client, args: argparse.Namespace) -> None:
    print(f"connected to {client.server_info.name if client.server_info else 'server'}, "
          f"protocol {client.protocol_version}")
    envelope = await call(client, "get_safety_envelope", {})
    print(f"robot {envelope['robot']}, approval mode {envelope['approval_mode']}, dry run {envelope['dry_run']}")

    state = await call(client, "get_robot_state", {})
    goal = list(state["joint_positions"])
    goal[-1] += args.delta
    print(f"planning: {envelope['joint_names'][-1]} {state['joint_positions'][-1]:+.3f} → {goal[-1]:+.3f} rad")
    plan = await call(client, "plan_to_joints", {"joint_positions": goal})
    print(f"plan {plan['plan_id']}: {plan['status']}, {plan['duration_s']:.2f} s, "
          f"peak speed {plan['max_joint_velocity_ratio']:.0%} of the limit")
    for violation in plan["violations"]:
        print(f"  {violation.get('severity')} {violation.get('code')}: {violation.get('detail')}")
    if plan["status"] == "rejected":
        raise Refused("the server rejected the plan; nothing moved")

    async def progress(value: float, total: float | None, message: str | None) -> None:
        print(f"  moving: {value:.0%}", end="\r", flush=True)

    report = await call(client, "execute_plan", {"plan_id": plan["plan_id"]}, progress_callback=progress)
    print(f"\nexecution {report['status']} in {report['duration_s']:.2f} s "
          f"(approval: {report['approval']['via']}, operator {report['approval'].get('operator')})")
    state = await call(client, "get_robot_state", {})
    position = state["tcp_pose"]["position"]
    print(f"TCP now at ({position['x']:.3f}, {position['y']:.3f}, {position['z']:.3f}) m in {state['frame_id']}")


if __name__ == "__main__":
    sys.exit(anyio.run(main, parse_args()))
