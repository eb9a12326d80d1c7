"""`armwarden serve` as a real subprocess over stdio, driven by the SDK's stdio client.

Covers: the bundled tool set, state, plan + approved execute, a refusal, the shutdown record on
client exit (also mid-motion), SIGTERM, and the start-up refusals (exit 2 before serving).
"""

from __future__ import annotations

import contextlib
import json
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path
from typing import Any

import anyio
import pytest
from mcp import Client, StdioServerParameters

from armwarden.audit import verify_file
from armwarden.policy import bundled_policy, load_policy, policy_digest
from armwarden.transport.pipes import MAX_LINE_BYTES
from tests.helpers import BUNDLED_TOOL_COUNT, CLI, HOME, REPO, SRC, child_env, records_of, stop_process, text_of, wait_for_record
from tests.server.harness import MODES, MotionStarted
from tests.server.harness import approve as approving


def backend_config(tmp_path: Path, speedup: float) -> Path:
    path = tmp_path / f"fake-{speedup:g}.yaml"
    path.write_text(f"speedup: {speedup}\n", encoding="utf-8")
    return path


def serve_params(audit: Path, config: Path) -> StdioServerParameters:
    return StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--audit-log", str(audit), "--backend-config", str(config),
              "--log-level", "WARNING"],
        env={"PYTHONPATH": str(SRC)},
        cwd=str(REPO),
    )


# ------------------------------------------------------------------ a session over stdio
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_stdio_daemon_serves_a_session_and_writes_a_shutdown_record_when_the_client_exits(tmp_path, mode) -> None:
    audit = tmp_path / "audit.jsonl"
    on_elicit = approving("carol")

    async with Client(serve_params(audit, backend_config(tmp_path, 20)), mode=mode, elicitation_callback=on_elicit) as client:
        tools = await client.list_tools()
        assert len(tools.tools) == BUNDLED_TOOL_COUNT
        assert {"execute_plan", "estop", "stop_motion", "get_robot_state"} <= {t.name for t in tools.tools}

        state = await client.call_tool("get_robot_state", {})
        assert not state.is_error
        assert state.structured_content["joint_positions"] == pytest.approx(HOME, abs=1e-6)

        # a refusal: the plan id is unknown
        refused = await client.call_tool("execute_plan", {"plan_id": "plan_does_not_exist"})
        assert refused.is_error and "UNKNOWN_PLAN" in text_of(refused)

        # 1 rad on joint 1 is above the soft step threshold: a human must approve
        goal = [1.0, *HOME[1:]]
        plan = await client.call_tool("plan_to_joints", {"joint_positions": goal})
        assert plan.structured_content["status"] == "needs_approval"
        done = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
        assert not done.is_error, text_of(done)
        assert done.structured_content["status"] == "succeeded"
        assert done.structured_content["approval"] == {"required": True, "operator": "carol", "via": "elicitation"}
        after = await client.call_tool("get_robot_state", {})
        assert after.structured_content["joint_positions"] == pytest.approx(goal, abs=1e-6)

    records = await wait_for_record(audit, lambda r: r["event"] == "shutdown")
    assert records[0]["event"] == "startup"
    assert records[-1]["event"] == "shutdown" and records[-1]["detail"] == "end of stdin"
    # the policy in force, once at start-up and on each plan (what `audit replay` compares against)
    digest = policy_digest(load_policy(bundled_policy()))
    assert records[0]["extra"]["policy_digest"] == digest
    assert [r["extra"]["replay"]["policy_digest"] for r in records if r["tool"] == "plan_to_joints"] == [digest]
    executed = [r for r in records if r["tool"] == "execute_plan" and r["outcome"] == "ok"]
    assert len(executed) == 1 and executed[0]["operator"] == "carol"
    assert len(on_elicit.prompts) == 1 and on_elicit.prompts[0].startswith("APPROVE ROBOT MOTION?")


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_stdio_client_exit_mid_motion_stops_the_arm_before_the_daemon_exits(tmp_path, mode) -> None:
    audit = tmp_path / "audit.jsonl"

    on_progress = MotionStarted()

    with anyio.fail_after(30):
        async with anyio.create_task_group() as group:
            async with Client(serve_params(audit, backend_config(tmp_path, 0.5)), mode=mode,
                              elicitation_callback=approving("dave")) as client:
                plan = await client.call_tool("plan_to_pose", {"position": {"x": 0.3069, "y": 0.0, "z": 0.35}})
                assert plan.structured_content["status"] == "ok"

                async def run() -> None:
                    with contextlib.suppress(Exception):  # the connection goes away under the call
                        await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]},
                                               progress_callback=on_progress)

                group.start_soon(run)
                await on_progress.event.wait()
            # the client (and the daemon's stdin) is gone while the arm moves

    records = await wait_for_record(audit, lambda r: r["event"] == "shutdown")
    events = [r["event"] for r in records]
    # held the moment the client's input ended, then the open call ended (answered as aborted, or
    # cancelled if the client stopped the daemon first), then the shutdown
    gone = events.index("client_gone")
    assert records[gone]["outcome"] == "latched"
    execution = next(r for r in records if r["event"] == "tool_call" and r["tool"] == "execute_plan")
    assert gone < records.index(execution) < events.index("shutdown") == len(records) - 1
    status = (execution.get("extra") or {}).get("result", {}).get("status")
    assert execution["outcome"] == "cancelled" or status == "aborted", execution


# ------------------------------------------------------------------ SIGTERM
class RawStdio:
    """Just enough JSON-RPC over a daemon's pipes to reach the middle of a motion (2025-11-25)."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.process = process
        self.buffer = b""
        self.next_id = 0

    def send(self, message: dict[str, Any]) -> None:
        self.send_line(json.dumps(message).encode())

    def send_line(self, line: bytes) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(line + b"\n")
        self.process.stdin.flush()

    def receive(self, timeout: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buffer:
            remaining = deadline - time.monotonic()
            assert remaining > 0, f"no message from the daemon within {timeout} s"
            ready, _, _ = select.select([self.process.stdout], [], [], remaining)
            if ready:
                chunk = os.read(self.process.stdout.fileno(), 65536)
                assert chunk, "the daemon closed stdout"
                self.buffer += chunk
        line, self.buffer = self.buffer.split(b"\n", 1)
        return json.loads(line)

    def request(self, method: str, params: dict[str, Any], until=None) -> dict[str, Any]:
        self.next_id += 1
        self.send({"jsonrpc": "2.0", "id": self.next_id, "method": method, "params": params})
        while True:
            message = self.receive()
            if message.get("id") == self.next_id or (until is not None and until(message)):
                return message


def test_sigterm_mid_motion_stops_the_arm_and_the_stdio_daemon_exits_with_a_shutdown_record(tmp_path) -> None:
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(
        [*CLI, "serve", "--audit-log", str(audit), "--backend-config", str(backend_config(tmp_path, 0.5)),
         "--log-level", "WARNING"],
        cwd=REPO, env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    try:
        rpc = RawStdio(process)
        hello = rpc.request("initialize", {"protocolVersion": "2025-11-25", "capabilities": {},
                                           "clientInfo": {"name": "sigterm-test", "version": "1"}})
        assert hello["result"]["serverInfo"]["name"] == "armwarden"
        rpc.send({"jsonrpc": "2.0", "method": "notifications/initialized"})
        plan = rpc.request("tools/call", {"name": "plan_to_pose",
                                          "arguments": {"position": {"x": 0.3069, "y": 0.0, "z": 0.35}}})
        plan_id = plan["result"]["structuredContent"]["plan_id"]
        progress = rpc.request(
            "tools/call", {"name": "execute_plan", "arguments": {"plan_id": plan_id}, "_meta": {"progressToken": "p1"}},
            until=lambda m: m.get("method") == "notifications/progress" and m["params"]["progress"] > 0,
        )
        assert progress.get("method") == "notifications/progress", progress  # moving, not finished

        started = time.monotonic()
        process.send_signal(signal.SIGTERM)
        returncode = process.wait(timeout=10)  # stdin stays open: the signal alone must end it
        elapsed = time.monotonic() - started
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        for stream in (process.stdin, process.stdout, process.stderr):
            stream.close()
    assert returncode == 0
    assert elapsed < 5
    records = records_of(audit)
    events = [r["event"] for r in records]
    assert events[0] == "startup"
    # the daemon stops the arm as soon as the signal arrives, and cancels the call in flight: the
    # execution is recorded either as interrupted (the cancellation won) or as stopped short of its goal
    execution = [r for r in records if r["tool"] == "execute_plan"]
    interrupted = "execution_interrupted" in events and any(r["outcome"] == "cancelled" for r in execution)
    stopped_short = any(((r.get("extra") or {}).get("result") or {}).get("status") == "aborted" for r in execution)
    assert interrupted or stopped_short, execution
    assert records[-1]["event"] == "shutdown" and records[-1]["detail"] == "signal SIGTERM"
    verdict = subprocess.run([*CLI, "audit", "verify", str(audit)], cwd=REPO, env=child_env(),
                             capture_output=True, text=True, timeout=60)
    assert verdict.returncode == 0, verdict.stdout


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_literal_non_finite_json_numbers_over_stdio_are_refused_and_nothing_moves(tmp_path, literal) -> None:
    # the SDK client would send NaN as null; a raw client can put the literal on the wire
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(
        [*CLI, "serve", "--audit-log", str(audit), "--log-level", "WARNING"],
        cwd=REPO, env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
    )
    try:
        rpc = RawStdio(process)
        rpc.request("initialize", {"protocolVersion": "2025-11-25", "capabilities": {},
                                   "clientInfo": {"name": "raw-nan", "version": "1"}})
        rpc.send({"jsonrpc": "2.0", "method": "notifications/initialized"})
        before = rpc.request("tools/call", {"name": "get_robot_state", "arguments": {}})["result"]["structuredContent"]
        answers = []
        for name, arguments in [
            ("plan_to_joints", f'{{"joint_positions": [{literal}, -0.78, 0, -2.35, 0, 1.57, 0.78]}}'),
            ("plan_to_pose", f'{{"position": {{"x": {literal}, "y": 0.0, "z": 0.4}}}}'),
            ("gripper_move", f'{{"width_m": {literal}}}'),
        ]:
            rpc.next_id += 1
            wire = (f'{{"jsonrpc": "2.0", "id": {rpc.next_id}, "method": "tools/call", '
                    f'"params": {{"name": "{name}", "arguments": {arguments}}}}}')
            process.stdin.write(wire.encode() + b"\n")
            process.stdin.flush()
            answer = rpc.receive()
            while answer.get("id") != rpc.next_id:
                answer = rpc.receive()
            answers.append(answer)
        after = rpc.request("tools/call", {"name": "get_robot_state", "arguments": {}})["result"]["structuredContent"]
    finally:
        process.stdin.close()
        process.wait(timeout=10)
        process.stdout.close()
    for answer in answers:  # a protocol error or an isError result; never a plan id, never a move
        result = answer.get("result")
        assert "error" in answer or (result is not None and result.get("isError")), answer
        assert not ((result or {}).get("structuredContent") or {}).get("plan_id"), answer
    assert after["joint_positions"] == before["joint_positions"]
    assert after["gripper"]["width_m"] == before["gripper"]["width_m"]
    verdict = subprocess.run([*CLI, "audit", "verify", str(audit)], cwd=REPO, env=child_env(),
                             capture_output=True, text=True, timeout=60)
    assert verdict.returncode == 0, verdict.stdout


# ------------------------------------------------------------------ refusing to start
def _invalid_policy(tmp_path: Path) -> Path:
    text = bundled_policy("fr3").read_text(encoding="utf-8")
    path = tmp_path / "bad-policy.yaml"
    path.write_text(text + "\nmystery_section: {loosen_everything: true}\n", encoding="utf-8")
    return path


START_REFUSALS = {
    "invalid_policy": (lambda tmp: ["--policy", str(_invalid_policy(tmp))], "mystery_section"),
    "unknown_backend": (lambda tmp: ["--backend", "warp-drive"], "invalid choice"),
    # rclpy blocked (see _without_rclpy), so the case holds whether or not the ROS extra is installed
    "unavailable_backend": (lambda tmp: ["--backend", "ros2"], "the ros2 backend is not available"),
    "unopenable_audit_log": (lambda tmp: ["--audit-log", str(tmp / "no-such-dir" / "audit.jsonl")], "does not exist"),
}


def _without_rclpy(tmp_path: Path) -> dict[str, str]:
    """child_env() with a sitecustomize that makes `import rclpy` fail (as without the ROS extra)."""
    blocker = tmp_path / "no-rclpy"
    blocker.mkdir()
    (blocker / "sitecustomize.py").write_text("import sys\nsys.modules['rclpy'] = None\n", encoding="utf-8")
    env = child_env()
    env["PYTHONPATH"] = f"{blocker}{os.pathsep}{env['PYTHONPATH']}"
    return env


@pytest.mark.parametrize("case", sorted(START_REFUSALS))
def test_serve_refuses_to_start_with_exit_2(tmp_path, case) -> None:
    extra, expected = START_REFUSALS[case]
    args = ["--audit-log", str(tmp_path / "audit.jsonl"), *extra(tmp_path)]
    env = _without_rclpy(tmp_path) if case == "unavailable_backend" else child_env()
    result = subprocess.run([*CLI, "serve", *args], cwd=REPO, env=env, stdin=subprocess.DEVNULL,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert expected in result.stderr, result.stderr
    assert result.stdout == ""  # nothing was served
    if case != "unopenable_audit_log":
        audit = tmp_path / "audit.jsonl"
        assert not audit.exists() or not any(r["event"] == "startup" for r in records_of(audit))


def test_serve_refuses_a_non_loopback_http_bind_without_tokens(tmp_path) -> None:
    # Belt and braces: hold the port on 127.0.0.1 so that, should the check ever regress, the
    # daemon could not start listening on all interfaces either (it would fail with another message).
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as guard:
        guard.bind(("127.0.0.1", 0))
        guard.listen(1)
        port = guard.getsockname()[1]
        result = subprocess.run(
            [*CLI, "serve", "--transport", "http", "--host", "0.0.0.0", "--port", str(port),
             "--audit-log", str(tmp_path / "audit.jsonl")],
            cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60,
        )
    assert result.returncode == 2, result.stderr
    assert "without bearer tokens" in result.stderr
    assert not (tmp_path / "audit.jsonl").exists()


# ------------------------------------------------------------------ duplicate ids, unreadable lines
def start_raw_daemon(tmp_path: Path, speedup: float, stderr: int = subprocess.DEVNULL,
                     ) -> tuple[subprocess.Popen, RawStdio, Path]:
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(
        [*CLI, "serve", "--audit-log", str(audit), "--backend-config", str(backend_config(tmp_path, speedup)),
         "--log-level", "WARNING"],
        cwd=REPO, env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=stderr,
    )
    rpc = RawStdio(process)
    hello = rpc.request("initialize", {"protocolVersion": "2025-11-25", "capabilities": {},
                                       "clientInfo": {"name": "raw-stdio", "version": "1"}})
    assert hello["result"]["serverInfo"]["name"] == "armwarden"
    rpc.send({"jsonrpc": "2.0", "method": "notifications/initialized"})
    return process, rpc, audit


def stop_raw_daemon(process: subprocess.Popen) -> None:
    assert process.stdin is not None and process.stdout is not None
    process.stdin.close()
    try:
        process.wait(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        process.stdout.close()


def start_motion(rpc: RawStdio) -> int:
    """Plan a motion that needs no approval, start `execute_plan` and return its request id once the
    arm moves (the call is open: its answer has not been sent)."""
    plan = rpc.request("tools/call", {"name": "plan_to_pose",
                                      "arguments": {"position": {"x": 0.3069, "y": 0.0, "z": 0.35}}})
    assert plan["result"]["structuredContent"]["status"] == "ok", plan
    progress = rpc.request(
        "tools/call", {"name": "execute_plan", "arguments": {"plan_id": plan["result"]["structuredContent"]["plan_id"]},
                       "_meta": {"progressToken": "motion"}},
        until=lambda m: m.get("method") == "notifications/progress" and m["params"]["progress"] > 0,
    )
    assert progress.get("method") == "notifications/progress", progress  # moving, not finished
    return rpc.next_id


def receive_until(rpc: RawStdio, predicate) -> dict[str, Any]:
    while True:
        message = rpc.receive()
        if predicate(message):
            return message


def reuse_the_id_of_an_open_motion(rpc: RawStdio) -> tuple[int, dict[str, Any]]:
    """Start a motion, then send `get_robot_state` under the motion call's still-open id: the id
    and the answer to that second request."""
    motion_id = start_motion(rpc)
    rpc.send({"jsonrpc": "2.0", "id": motion_id, "method": "tools/call",
              "params": {"name": "get_robot_state", "arguments": {}}})
    return motion_id, receive_until(rpc, lambda m: m.get("id") == motion_id)


def test_a_request_reusing_the_id_of_an_open_motion_call_is_refused_and_the_motion_completes(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=0.5)
    try:
        motion_id, refusal = reuse_the_id_of_an_open_motion(rpc)
        done = receive_until(rpc, lambda m: m.get("id") == motion_id)
    finally:
        stop_raw_daemon(process)
    assert refusal["error"]["code"] == -32600
    assert "already in use by an open request" in refusal["error"]["message"]
    assert done["result"]["structuredContent"]["status"] == "succeeded", done
    refused = [r for r in records_of(audit) if r["event"] == "request_refused"]
    assert len(refused) == 1 and refused[0]["tool"] == "get_robot_state"


# sync on purpose, like the other raw-daemon tests: the daemon is driven through blocking pipe reads
def test_an_open_motion_call_stays_cancellable_after_a_duplicate_id_was_refused(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=0.5)
    try:
        motion_id, refusal = reuse_the_id_of_an_open_motion(rpc)
        rpc.send({"jsonrpc": "2.0", "method": "notifications/cancelled", "params": {"requestId": motion_id}})
        # the call's own record is written when the cancelled call ends, after the interruption's
        records = anyio.run(wait_for_record, audit, lambda r: r["tool"] == "execute_plan" and r["outcome"] == "cancelled")
        state = rpc.request("tools/call", {"name": "get_motion_status", "arguments": {}})
    finally:
        stop_raw_daemon(process)
    assert "error" in refusal
    assert any(r["event"] == "execution_interrupted" for r in records)
    assert state["result"]["structuredContent"]["executing"] is False


@pytest.mark.parametrize(("line", "code"), [(b"this is not json", -32700), (b'{"jsonrpc": "2.0", "id": [1]}', -32600)])
def test_an_unreadable_line_gets_a_json_rpc_error_and_the_session_keeps_working(tmp_path, line, code) -> None:
    process, rpc, _ = start_raw_daemon(tmp_path, speedup=20)
    try:
        rpc.send_line(line)
        error = rpc.receive()
        state = rpc.request("tools/call", {"name": "get_robot_state", "arguments": {}})
    finally:
        stop_raw_daemon(process)
    assert error == {"jsonrpc": "2.0", "id": None, "error": error["error"]} and error["error"]["code"] == code
    assert state["result"]["structuredContent"]["joint_positions"] == pytest.approx(HOME, abs=1e-6)


def test_an_estop_whose_arguments_are_not_an_object_latches_and_is_recorded(tmp_path) -> None:
    """Found by review: the SDK refused such a call (-32602) before the tool ran: the arm was held
    on receipt, but the e-stop never latched and no call was recorded."""
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=20)
    try:
        answer = rpc.request("tools/call", {"name": "estop", "arguments": ["person in the cell"]})
        status = rpc.request("tools/call", {"name": "get_safety_status", "arguments": {}})
    finally:
        stop_raw_daemon(process)
    assert answer["result"]["structuredContent"]["estopped"] is True
    assert status["result"]["structuredContent"]["estopped"] is True
    [call] = [r for r in records_of(audit) if r["event"] == "tool_call" and r["tool"] == "estop"]
    assert call["outcome"] == "ok" and call["arguments"] == {"reason": ["person in the cell"]}


def test_a_call_the_sdk_refuses_for_malformed_params_is_recorded(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=20)
    try:
        answer = rpc.request("tools/call", {"name": "gripper_move", "arguments": [0.04]})
        # written by its own task (a stop behind it is never held up by this fsync)
        records = anyio.run(wait_for_record, audit, lambda r: r["event"] == "request_refused")
        state = rpc.request("tools/call", {"name": "get_robot_state", "arguments": {}})
    finally:
        stop_raw_daemon(process)
    assert answer["error"]["code"] == -32602
    [refused] = [r for r in records if r["event"] == "request_refused"]
    assert refused["tool"] == "gripper_move" and refused["outcome"] == "invalid_params"
    assert refused["arguments"] == [0.04] and "not an object" in refused["detail"]
    assert "result" in state


# ------------------------------------------------------------------ what serving on stdio imports
WATCH_IMPORTS = """
import json, sys
seen = []

class Watch:
    # records who imports uvicorn/starlette: the first frame outside the import machinery
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("uvicorn", "starlette"):
            frame = sys._getframe(1)
            while frame is not None and (frame.f_code.co_filename.startswith("<frozen")
                                         or "importlib" in frame.f_code.co_filename):
                frame = frame.f_back
            seen.append([name, frame.f_globals.get("__name__") if frame is not None else None])
        return None

sys.meta_path.insert(0, Watch())
from armwarden.cli import main
code = main(sys.argv[2:])
report = {"code": code, "importers": seen, "armwarden": sorted(m for m in sys.modules if m.startswith("armwarden"))}
open(sys.argv[1], "w").write(json.dumps(report))
"""


def test_serving_on_stdio_imports_no_http_module_of_armwarden(tmp_path) -> None:
    # The MCP SDK (2.x) imports Starlette and uvicorn itself on `import mcp`; what ArmWarden controls
    # is that none of its own modules imports them, nor its HTTP transport, on the stdio path.
    report_path = tmp_path / "imports.json"
    audit = tmp_path / "audit.jsonl"
    result = subprocess.run(
        [sys.executable, "-c", WATCH_IMPORTS, str(report_path), "serve", "--audit-log", str(audit)],
        cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60, check=False,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(report_path.read_text(encoding="utf-8"))
    assert report["code"] == 0
    assert [r["event"] for r in records_of(audit)] == ["startup", "shutdown"]  # it served stdio, then stdin ended
    assert "armwarden.transport.stdio" in report["armwarden"]
    http_modules = {"armwarden.transport.http", "armwarden.transport.bearer", "armwarden.transport.abandoned",
                    "armwarden.transport.request_body", "armwarden.transport.mcp_middleware"}
    assert not http_modules & set(report["armwarden"])
    assert [entry for entry in report["importers"] if (entry[1] or "").startswith("armwarden")] == []


def test_an_estop_request_holds_the_arm_as_it_is_read_and_the_call_then_latches(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=0.5)
    try:
        motion_id = start_motion(rpc)
        estop = rpc.request("tools/call", {"name": "estop", "arguments": {"reason": "hand in the cell"}})
        done = receive_until(rpc, lambda m: m.get("id") == motion_id)
    finally:
        stop_raw_daemon(process)
    assert estop["result"]["structuredContent"]["estopped"] is True
    assert done["result"]["structuredContent"]["status"] == "aborted", done
    records = records_of(audit)
    held = [r for r in records if r["event"] == "stop_on_receipt"]
    assert len(held) == 1 and held[0]["tool"] == "estop" and held[0]["outcome"] == "stopped"
    call = next(r for r in records if r["event"] == "tool_call" and r["tool"] == "estop")
    assert held[0]["seq"] < call["seq"]  # held before the call itself ran and was recorded


# ------------------------------------------------------------------ how stdin and stdout are served
HELLO = {"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
    "protocolVersion": "2025-11-25", "capabilities": {}, "clientInfo": {"name": "raw-stdio", "version": "1"}}}
INITIALIZED = {"jsonrpc": "2.0", "method": "notifications/initialized"}
STATE_CALL = {"jsonrpc": "2.0", "id": 2, "method": "tools/call", "params": {"name": "get_robot_state", "arguments": {}}}


def serve_command(audit: Path) -> list[str]:
    return [*CLI, "serve", "--audit-log", str(audit), "--log-level", "INFO"]


def answers_of(wire: bytes) -> dict[Any, dict[str, Any]]:
    return {message.get("id"): message for message in map(json.loads, wire.decode().splitlines())}


def test_a_client_on_sockets_as_node_launches_servers_is_served_from_the_event_loop(tmp_path) -> None:
    stdin_parent, stdin_child = socket.socketpair()  # libuv (Claude Desktop, Cursor, the TS SDK) uses socket pairs
    stdout_parent, stdout_child = socket.socketpair()
    process = subprocess.Popen(serve_command(tmp_path / "audit.jsonl"), stdin=stdin_child, stdout=stdout_child,
                               stderr=subprocess.PIPE, cwd=REPO, env=child_env())
    stdin_child.close()
    stdout_child.close()
    wire = b""
    try:
        for message in (HELLO, INITIALIZED, STATE_CALL):
            stdin_parent.sendall(json.dumps(message).encode() + b"\r\n")  # CR LF ends a line, as for the SDK
        stdout_parent.settimeout(30)
        while wire.count(b"\n") < 2:
            chunk = stdout_parent.recv(65536)
            assert chunk, "the daemon closed stdout"
            wire += chunk
        stdin_parent.shutdown(socket.SHUT_WR)  # end of input: the daemon exits
        _, stderr = process.communicate(timeout=30)
    finally:
        stop_process(process, 10)
        stdin_parent.close()
        stdout_parent.close()
    answers = answers_of(wire)
    assert answers[1]["result"]["serverInfo"]["name"] == "armwarden"
    assert len(answers[2]["result"]["structuredContent"]["joint_positions"]) == 7
    assert b"serving stdin and stdout from the event loop" in stderr
    assert process.returncode == 0


def test_stdin_from_a_terminal_is_served_by_the_sdks_threads(tmp_path) -> None:
    controller, terminal = pty.openpty()  # a terminal's flags are shared with whatever else uses it
    tty.setraw(terminal)
    process = subprocess.Popen(serve_command(tmp_path / "audit.jsonl"), stdin=terminal, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, cwd=REPO, env=child_env())
    os.close(terminal)
    assert process.stdout is not None
    try:
        os.write(controller, b"".join(json.dumps(m).encode() + b"\n" for m in (HELLO, INITIALIZED, STATE_CALL)))
        wire = _read_until_answered(process.stdout, 2)
    finally:
        os.close(controller)  # the terminal hangs up: end of input
        stop_process(process, 10)
        stderr = process.stderr.read() if process.stderr is not None else b""
        process.stdout.close()
    assert b"the SDK's threads serve them" in stderr
    answers = answers_of(wire)
    assert len(answers[2]["result"]["structuredContent"]["joint_positions"]) == 7


@pytest.mark.anyio
async def test_a_client_that_stops_reading_cannot_hold_back_an_estop(tmp_path) -> None:
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(serve_command(audit), stdin=subprocess.PIPE, stdout=subprocess.PIPE,  # noqa: ASYNC220 - set-up
                               stderr=subprocess.DEVNULL, cwd=REPO, env=child_env())
    assert process.stdin is not None and process.stdout is not None
    polls = [{**STATE_CALL, "id": 100 + i} for i in range(200)]  # ~280 KB of answers: stdout fills up
    estop = {"jsonrpc": "2.0", "id": 99, "method": "tools/call",
             "params": {"name": "estop", "arguments": {"reason": "the client stopped reading"}}}
    lines = b"".join(json.dumps(m).encode() + b"\n" for m in (HELLO, INITIALIZED, *polls, estop))
    try:
        await anyio.to_thread.run_sync(_write_all, process.stdin, lines)  # nothing is read meanwhile
        records = await wait_for_record(audit, lambda r: r["event"] == "tool_call" and r["tool"] == "estop", 30)
        assert any(r["event"] == "stop_on_receipt" and r["tool"] == "estop" for r in records)
        wire = await anyio.to_thread.run_sync(_read_until_answered, process.stdout, 99)  # now read
        process.stdin.close()
    finally:
        stop_process(process, 10)
        process.stdout.close()
    answers = answers_of(wire)
    assert answers[99]["result"]["structuredContent"]["estopped"] is True
    assert {m["id"] for m in polls} <= answers.keys()


def _write_all(stream: Any, data: bytes) -> None:
    stream.write(data)
    stream.flush()


def _read_until_answered(stream: Any, request_id: int, timeout_s: float = 30.0) -> bytes:
    wire, deadline = b"", time.monotonic() + timeout_s
    while f'"id":{request_id},'.encode() not in wire:
        assert time.monotonic() < deadline, f"no answer to request {request_id} within {timeout_s} s"
        if select.select([stream], [], [], 0.5)[0]:
            chunk = os.read(stream.fileno(), 65536)
            assert chunk, "the daemon closed stdout"
            wire += chunk
    while not wire.endswith(b"\n"):  # the rest of that answer's line
        wire += os.read(stream.fileno(), 65536)
    return wire


def test_a_line_over_the_limit_is_answered_as_unreadable_and_the_session_goes_on(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=1)
    try:
        rpc.send_line(b'{"jsonrpc":"2.0","id":7,"method":"tools/call","params":{"pad":"' + b"x" * (MAX_LINE_BYTES + 1) + b'"}}')
        refused = rpc.receive()
        state = rpc.request("tools/call", {"name": "get_robot_state", "arguments": {}})
    finally:
        stop_raw_daemon(process)
    assert refused["id"] is None and refused["error"]["code"] == -32700
    assert len(state["result"]["structuredContent"]["joint_positions"]) == 7
    assert any(r["event"] == "request_refused" and r["outcome"] == "unreadable" for r in records_of(audit))


def test_a_client_streaming_an_endless_line_cannot_keep_the_daemon_from_stopping_on_sigterm(tmp_path) -> None:
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(serve_command(audit), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, cwd=REPO, env=child_env())
    assert process.stdin is not None
    streaming = threading.Event()

    def stream() -> None:
        try:
            process.stdin.write(json.dumps(HELLO).encode() + b"\n" + b'{"pad":"')
            while True:
                process.stdin.write(b"x" * 65536)
                streaming.set()
        except (BrokenPipeError, ValueError, OSError):
            return  # the daemon exited

    feeder = threading.Thread(target=stream, daemon=True)
    feeder.start()
    try:
        assert streaming.wait(30)
        time.sleep(1.0)  # well past the line limit, and still coming
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=15) is not None
    finally:
        stop_process(process, 5)
        feeder.join(5)
    assert [r["event"] for r in records_of(audit)][-1] == "shutdown"


def test_calls_read_before_the_input_ends_are_answered(tmp_path) -> None:
    """`printf '<requests>' | armwarden serve`: the client writes its requests and closes its end."""
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(serve_command(audit), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.DEVNULL, cwd=REPO, env=child_env())
    plan = {"jsonrpc": "2.0", "id": 3, "method": "tools/call",
            "params": {"name": "plan_to_pose", "arguments": {"position": {"x": 0.4, "y": 0.05, "z": 0.35}}}}
    wire, _ = process.communicate(b"".join(json.dumps(m).encode() + b"\n" for m in (HELLO, INITIALIZED, STATE_CALL, plan)),
                                  timeout=60)
    answers = answers_of(wire)
    assert len(answers[2]["result"]["structuredContent"]["joint_positions"]) == 7
    planned = answers[3]["result"]  # answered: planned, or refused once the e-stop latched as the input ended
    assert planned.get("structuredContent", {}).get("status") in ("ok", "needs_approval") or (
        planned["isError"] and "ESTOPPED" in planned["content"][0]["text"]), planned
    assert process.returncode == 0
    assert [r["event"] for r in records_of(audit)][-1] == "shutdown"


def test_a_motion_open_when_the_input_ends_is_stopped_at_once_then_answered(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=0.5)
    try:
        motion_id = start_motion(rpc)
        assert process.stdin is not None
        process.stdin.close()  # the client leaves mid-motion
        done = receive_until(rpc, lambda m: m.get("id") == motion_id)
        assert process.wait(timeout=30) == 0
    finally:
        stop_raw_daemon(process)
    assert done["result"]["structuredContent"]["status"] in ("aborted", "stopped"), done
    records = records_of(audit)
    gone = [r for r in records if r["event"] == "client_gone"]
    assert len(gone) == 1 and gone[0]["outcome"] == "latched"
    execution = next(r for r in records if r["event"] == "tool_call" and r["tool"] == "execute_plan")
    assert gone[0]["seq"] < execution["seq"] < records[-1]["seq"] and records[-1]["event"] == "shutdown"


def test_a_motion_call_read_just_before_the_input_ends_never_starts(tmp_path) -> None:
    """The client wrote `execute_plan` and left: nothing may start moving for a client that can no
    longer stop it (the e-stop is latched as the input ends; the call is answered refused)."""
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=0.5)
    try:
        plan = rpc.request("tools/call", {"name": "plan_to_pose",
                                          "arguments": {"position": {"x": 0.3069, "y": 0.0, "z": 0.35}}})
        plan_id = plan["result"]["structuredContent"]["plan_id"]
        rpc.send({"jsonrpc": "2.0", "id": 50, "method": "tools/call",
                  "params": {"name": "execute_plan", "arguments": {"plan_id": plan_id}}})
        assert process.stdin is not None
        process.stdin.close()
        done = receive_until(rpc, lambda m: m.get("id") == 50)
        assert process.wait(timeout=30) == 0
    finally:
        stop_raw_daemon(process)
    result = done["result"]
    assert result.get("isError") or result["structuredContent"]["status"] in ("aborted", "stopped"), done
    records = records_of(audit)
    assert not any(r["tool"] == "execute_plan" and "succeeded" in str(r.get("detail")) for r in records)


# ------------------------------------------------------------------ the client closes stdout
def test_a_client_that_closes_the_daemons_stdout_mid_motion_stops_the_arm_and_the_daemon_exits_cleanly(
        tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, 0.5, stderr=subprocess.PIPE)
    try:
        start_motion(rpc)
        assert process.stdout is not None
        process.stdout.close()  # the client stops listening: the motion's next progress note meets EPIPE
        _, stderr = process.communicate(timeout=30)
    finally:
        stop_process(process, 10)

    assert process.returncode == 0
    assert b"Traceback" not in stderr and b"the client closed the daemon's stdout" in stderr
    records = records_of(audit)
    assert verify_file(audit).ok
    assert records[-1]["event"] == "shutdown" and records[-1]["detail"] == "the client closed stdout"
    execution = next(r for r in records if r["event"] == "tool_call" and r["tool"] == "execute_plan")
    status = (execution.get("extra") or {}).get("result", {}).get("status")
    assert execution["outcome"] == "cancelled" or status == "aborted", execution


def test_a_client_on_sockets_that_closes_the_daemons_stdout_ends_the_session_cleanly(tmp_path) -> None:
    stdin_parent, stdin_child = socket.socketpair()
    stdout_parent, stdout_child = socket.socketpair()
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(serve_command(audit), stdin=stdin_child, stdout=stdout_child,
                               stderr=subprocess.PIPE, cwd=REPO, env=child_env())
    stdin_child.close()
    stdout_child.close()
    try:
        for message in (HELLO, INITIALIZED):
            stdin_parent.sendall(json.dumps(message).encode() + b"\n")
        stdout_parent.settimeout(30)
        assert b"serverInfo" in stdout_parent.recv(65536)
        stdout_parent.close()  # gone, while its input stays open
        for _ in range(3):  # answers now have nowhere to go
            stdin_parent.sendall(json.dumps(STATE_CALL).encode() + b"\n")
        _, stderr = process.communicate(timeout=30)
    finally:
        stop_process(process, 10)
        stdin_parent.close()

    assert process.returncode == 0
    assert b"Traceback" not in stderr and b"the client closed the daemon's stdout" in stderr
    assert records_of(audit)[-1]["detail"] == "the client closed stdout"
