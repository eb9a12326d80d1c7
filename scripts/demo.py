#!/usr/bin/env python3
"""A scripted ArmWarden session over real stdio, printed as a readable transcript.

The script starts the daemon exactly as a desktop MCP client would (`python -m armwarden.cli
serve` as a subprocess speaking MCP on stdin/stdout) with the bundled FR3 policy, the fake
backend sped up through `--backend-config`, and a fresh audit log, then drives it with the
official MCP SDK client:

 1. read the safety envelope;
 2. plan a large joint move (over the policy's soft travel threshold, so it needs approval) and
    save the preview PNG the plan returns;
 3. execute it: the server asks for approval, the script prints the prompt and approves;
 4. plan a TCP pose inside the policy's `monitor` keep-out zone: rejected with KEEP_OUT;
 5. e-stop, then try to plan: refused while latched;
 6. reset the e-stop (the server asks, the script approves) and plan again: allowed;
 7. close the session (the daemon stops the arm and writes its final record) and run
    `armwarden audit verify` on the log.

Every step checks what the server answered; the script exits 1 at the first step that does not
behave as expected, 0 when all do. Files (audit log, preview) go to --out (default: a new
temporary folder, kept and printed at the end).

    python scripts/demo.py [--out DIR] [--mode auto|legacy|2026-07-28]
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import sys
import tempfile
import textwrap
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
from mcp import Client, StdioServerParameters

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src"
OPERATOR = "demo-script"
#: fake backend wiring: execute 20× faster than real time so the demo takes seconds
BACKEND_CONFIG = "speedup: 20.0\n"


class StepFailed(Exception):
    """A step did not behave as the safety design says it must."""


def say(text: str = "", indent: int = 0) -> None:
    print(textwrap.indent(text, " " * indent), flush=True)


def step(number: int, title: str) -> None:
    say()
    say(f"── step {number}: {title} " + "─" * max(0, 60 - len(title)))


def expect(condition: bool, what: str) -> None:
    if not condition:
        raise StepFailed(what)
    say(f"✔ {what}", 2)


def text_of(result: types.CallToolResult) -> str:
    return " ".join(block.text for block in result.content if isinstance(block, types.TextContent))


def structured(result: types.CallToolResult, tool: str) -> dict[str, Any]:
    if result.is_error or result.structured_content is None:
        raise StepFailed(f"{tool} failed: {text_of(result)}")
    return result.structured_content


def show_plan(plan: dict[str, Any]) -> None:
    say(f"status={plan['status']}  plan_id={plan['plan_id']}  requires_approval={plan['requires_approval']}", 2)
    say(f"duration {plan['duration_s']:.2f} s, peak speed {plan['max_joint_velocity_ratio']:.0%} of the limit, "
        f"largest joint travel {plan['max_joint_travel_rad']:.3f} rad, TCP path {plan['tcp_path_length_m']:.3f} m", 2)
    for violation in plan["violations"]:
        say(f"violation {violation.get('code')} ({violation.get('severity')}): {violation.get('detail')}", 2)


class Approver:
    """Answers the server's approval prompts like a human at the client would (here: always yes)."""

    def __init__(self) -> None:
        self.prompts: list[str] = []

    async def __call__(self, context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        message = getattr(params, "message", "")
        self.prompts.append(message)
        say("┌ the server asks a human:", 2)
        say(textwrap.indent(message, "│ ", predicate=lambda line: True), 2)
        say(f"└ {OPERATOR} answers: approve", 2)
        return types.ElicitResult(action="accept", content={"approve": True, "operator": OPERATOR})


async def run_session(out: Path, mode: str) -> None:
    audit_log = out / "audit.jsonl"
    backend_config = out / "fake-backend.yaml"
    backend_config.write_text(BACKEND_CONFIG, encoding="utf-8")
    env = {"PYTHONPATH": os.pathsep.join(filter(None, [str(SRC), os.environ.get("PYTHONPATH", "")]))}
    server = StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--backend", "fake", "--backend-config", str(backend_config),
              "--audit-log", str(audit_log), "--log-level", "WARNING"],
        env=env,
        cwd=str(out),
    )
    approver = Approver()
    say(f"$ {sys.executable} -m armwarden.cli serve --backend fake --backend-config {backend_config} "
        f"--audit-log {audit_log}")
    async with Client(server, mode=mode, elicitation_callback=approver) as client:
        say(f"connected: {client.server_info.name if client.server_info else '?'} "
            f"(protocol {client.protocol_version})")

        step(1, "read the safety envelope")
        envelope = structured(await client.call_tool("get_safety_envelope", {}), "get_safety_envelope")
        zones = {zone["name"]: zone for zone in envelope["keep_out"]}
        say(f"workspace box {envelope['workspace_box']}; keep-out zones: {', '.join(zones)}", 2)
        expect("monitor" in zones, "the policy defines the `monitor` keep-out zone")
        state = structured(await client.call_tool("get_robot_state", {}), "get_robot_state")
        home = state["joint_positions"]
        say(f"joints [rad]: {[round(q, 3) for q in home]}", 2)

        step(2, "plan a large joint move (does not move the arm) and save its preview")
        goal = list(home)
        goal[0] += 0.85  # over soft_joint_step_rad (0.8 rad) → a human must approve
        result = await client.call_tool("plan_to_joints", {"joint_positions": goal})
        plan = structured(result, "plan_to_joints")
        show_plan(plan)
        expect(plan["status"] == "needs_approval", "the plan is valid but outside the soft envelope: needs_approval")
        expect(any(v.get("code") == "LARGE_MOTION" for v in plan["violations"]), "the reason is LARGE_MOTION (soft)")
        images = [block for block in result.content if isinstance(block, types.ImageContent)]
        expect(len(images) == 1 and images[0].mime_type == "image/png", "the plan came with a PNG preview")
        preview = out / "preview.png"
        preview.write_bytes(base64.b64decode(images[0].data))
        say(f"preview saved to {preview} ({preview.stat().st_size} bytes)", 2)

        step(3, "execute: the server asks for approval, the operator approves")
        progress_seen: list[float] = []

        async def on_progress(progress: float, total: float | None, message: str | None) -> None:
            progress_seen.append(progress)

        report = structured(await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]},
                                                    progress_callback=on_progress), "execute_plan")
        say(f"status={report['status']}  duration {report['duration_s']:.2f} s  approval={report['approval']}", 2)
        expect(len(approver.prompts) == 1 and "APPROVE ROBOT MOTION" in approver.prompts[0],
               "exactly one approval prompt, stating the server's facts")
        expect(report["status"] == "succeeded", "the motion ran to the goal")
        expect(report["approval"].get("operator") == OPERATOR, "the approval is recorded with the operator's name")
        state = structured(await client.call_tool("get_robot_state", {}), "get_robot_state")
        expect(abs(state["joint_positions"][0] - goal[0]) < 1e-3, "the arm is at the planned goal")
        replay = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})
        say(f"replay → {text_of(replay)}", 2)
        expect(replay.is_error and len(approver.prompts) == 1, "a plan runs at most once (replay refused, no prompt)")

        step(4, "plan a TCP pose inside the `monitor` keep-out zone")
        zone = zones["monitor"]
        inside = {"x": zone["min"][0] + 0.03, "y": zone["min"][1] + 0.03, "z": 0.30}
        say(f"target {inside} (zone min {zone['min']}, max {zone['max']})", 2)
        rejected = structured(await client.call_tool("plan_to_pose", {"position": inside}), "plan_to_pose")
        show_plan(rejected)
        expect(rejected["status"] == "rejected", "the plan is rejected")
        expect(any(v.get("code") == "KEEP_OUT" for v in rejected["violations"]), "the reason is KEEP_OUT (hard)")
        if rejected["plan_id"]:
            attempt = await client.call_tool("execute_plan", {"plan_id": rejected["plan_id"]})
            say(f"execute anyway → {text_of(attempt)}", 2)
            expect(attempt.is_error and len(approver.prompts) == 1,
                   "a rejected plan cannot be executed, and no human is asked")

        step(5, "software e-stop, then try to move")
        estop = structured(await client.call_tool("estop", {"reason": "demo: operator pressed stop"}), "estop")
        event = estop["estop_event"]["number"]
        say(f"e-stop #{event} latched: {estop['estop_event']['reason']!r}", 2)
        expect(estop["estopped"] is True, "the e-stop is latched")
        blocked = await client.call_tool("plan_to_joints", {"joint_positions": home})
        say(f"plan_to_joints → {text_of(blocked)}", 2)
        expect(blocked.is_error and "ESTOPPED" in text_of(blocked), "planning is refused while the e-stop is latched")
        status = structured(await client.call_tool("get_safety_status", {}), "get_safety_status")
        expect(status["estopped"] is True, "get_safety_status still answers and reports the latch")

        step(6, "reset the e-stop (a human must approve), then plan again")
        reset = structured(await client.call_tool("reset_estop", {}), "reset_estop")
        say(f"reset → {reset}", 2)
        expect(len(approver.prompts) == 2 and f"#{event}" in approver.prompts[1],
               f"the reset prompt names e-stop event #{event}")
        expect(reset["estopped"] is False and reset["released_event"] == event, f"e-stop #{event} released")
        again = structured(await client.call_tool("plan_to_joints", {"joint_positions": home}), "plan_to_joints")
        show_plan(again)
        expect(again["status"] in ("ok", "needs_approval"), "planning works again after the reset")

    step(7, "session closed; verify the audit log")
    command = [sys.executable, "-m", "armwarden.cli", "audit", "verify", str(audit_log)]
    say(f"$ armwarden audit verify {audit_log}", 2)
    with anyio.fail_after(60):
        verified = await anyio.run_process(command, check=False, env=os.environ | env)
    say((verified.stdout + verified.stderr).decode("utf-8", "replace").strip(), 4)
    expect(verified.returncode == 0, "the hash chain of the audit log is intact")
    lines = [line for line in audit_log.read_text(encoding="utf-8").splitlines() if line.strip()]
    last = json.loads(lines[-1])
    expect(last.get("event") == "shutdown", f"the daemon's last record is its shutdown ({last.get('detail')})")
    say(f"{len(lines)} audit records in {audit_log}", 2)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Scripted ArmWarden demo over stdio (fake backend).")
    parser.add_argument("--out", type=Path, default=None, help="folder for the audit log and preview (default: new temp dir)")
    parser.add_argument("--mode", default="auto", choices=["auto", "legacy", "2026-07-28"], help="MCP protocol mode")
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="armwarden-demo-"))
    out.mkdir(parents=True, exist_ok=True)
    out = out.resolve()
    say("ArmWarden demo: bundled FR3 policy, fake backend, real stdio")
    try:
        anyio.run(run_session, out, args.mode)
    except StepFailed as exc:
        say(f"\n✘ FAILED: {exc}")
        say(f"files kept in {out}")
        return 1
    say(f"\nAll steps behaved as expected. Files: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
