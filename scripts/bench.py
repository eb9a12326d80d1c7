#!/usr/bin/env python3
"""ArmWarden benchmarks: every figure is a ratio or a percentile measured in this one run.

    python scripts/bench.py                 # all sections
    python scripts/bench.py envelope        # one section
    python scripts/bench.py --json out.json # also write the raw figures

Sections
- envelope: cost of the full envelope check (every link, self-collision, keep-out, workspace)
  on a typical 0.5 rad, ~1.5 s FR3 plan, against bare Pinocchio FK over the same samples.
- server: round trips through the official MCP SDK client — plan_to_pose (all links checked, with
  and without the preview picture) and get_robot_state in memory, get_robot_state over real
  stdio, and the audit log's cost per call.
- estop: e-stop latency while 8 HTTP clients load the daemon (a subprocess on 127.0.0.1): from
  the request reaching ArmWarden to the backend stop being issued, and to the arm being still
  (the fake holds the arm in the thread that issues the stop; its control thread never commands
  a later position).

Timing thresholds live here, never in unit tests: the machines are shared and noisy. Each
target is reported as met or missed; nothing is asserted.
"""

from __future__ import annotations

import argparse
import importlib
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from armwarden.policy import bundled_policy, load_policy
from armwarden.preflight import load_runtime_model

SRC = Path(__file__).resolve().parents[1] / "src"
TRIVIAL_SERVER = Path(__file__).resolve().parent / "_bench" / "trivial_server.py"

READY = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
TYPICAL_DELTA = np.array([0.5, 0.25, -0.2, 0.3, 0.2, -0.3, 0.4])  # largest joint travel 0.5 rad


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def _time_us(fn: Callable[[], object], repeats: int) -> list[float]:
    fn()  # warm-up
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append((time.perf_counter() - start) * 1e6)
    return out


def bench_envelope(repeats: int = 400) -> dict[str, float]:
    import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

    runtime = load_runtime_model(load_policy(bundled_policy("fr3")))
    robot, envelope, planner = runtime.robot, runtime.envelope, runtime.planner
    trajectory = planner.plan_to_joints(READY, READY + TYPICAL_DELTA, velocity_scaling=0.15).trajectory
    if trajectory is None:
        raise RuntimeError("the benchmark motion could not be planned")
    report = envelope.check(trajectory)
    assert not report.violations, report.violations
    # the samples the sweep bound requires (fine), and those a clean plan actually evaluates (the
    # coarse pass; see Envelope._check_geometry)
    _, q_fine, _ = envelope.sample_path(trajectory.times, trajectory.positions)
    n_evaluated = report.samples_checked
    q_evaluated = q_fine[np.linspace(0, len(q_fine) - 1, n_evaluated).round().astype(int)]
    model, data = robot.model, robot.data
    tcp_id = model.getFrameId(robot.tcp_frame)

    def bare_fk_tcp(samples: np.ndarray) -> Callable[[], None]:
        def run() -> None:
            for q in samples:
                pin.forwardKinematics(model, data, q)
                pin.updateFramePlacement(model, data, tcp_id).translation  # noqa: B018 - read it, as a check must
        return run

    def bare_fk_bodies() -> None:
        robot.joint_frames(q_fine)

    def full_check() -> None:
        envelope.check(trajectory)

    # interleave them so that machine noise hits them alike
    full, tcp, tcp_eval, bodies = [], [], [], []
    fk_fine, fk_eval = bare_fk_tcp(q_fine), bare_fk_tcp(q_evaluated)
    for _ in range(repeats):
        full += _time_us(full_check, 1)
        tcp += _time_us(fk_fine, 1)
        tcp_eval += _time_us(fk_eval, 1)
        bodies += _time_us(bare_fk_bodies, 1)
    n = len(q_fine)
    full_med, tcp_med, bodies_med = statistics.median(full), statistics.median(tcp), statistics.median(bodies)
    eval_med = statistics.median(tcp_eval)
    return {
        "plan_duration_s": trajectory.duration_s,
        "plan_waypoints": len(trajectory.times),
        "evaluated_samples": n_evaluated,
        "bare_fk_tcp_evaluated_us_median": eval_med,
        "ratio_full_to_fk_tcp_evaluated": full_med / eval_med,
        "checked_samples": n,
        "capsules": len(robot.capsules),
        "self_collision_pairs": len(envelope.self_collision_pairs),
        "keep_out_zones": len(envelope.limits.keep_out),
        "full_check_ms_median": full_med / 1e3,
        "full_check_ms_p95": _percentile(full, 95) / 1e3,
        "checked_samples_per_s": n / (full_med / 1e6),
        "bare_fk_tcp_us_median": tcp_med,
        "bare_fk_bodies_us_median": bodies_med,
        "ratio_full_to_fk_tcp": full_med / tcp_med,
        "ratio_full_to_fk_bodies": full_med / bodies_med,
    }


def _report_envelope(r: dict[str, float]) -> None:
    print("## envelope")
    print(
        f"typical plan: {r['plan_duration_s']:.2f} s, {r['plan_waypoints']} waypoints, largest joint travel 0.5 rad; "
        f"the sweep bound needs {r['checked_samples']} samples, the coarse-to-fine check evaluated "
        f"{r['evaluated_samples']}; {r['capsules']} capsules + TCP, "
        f"{r['self_collision_pairs']} self-collision pairs, {r['keep_out_zones']} keep-out zones"
    )
    print(f"full check: {r['full_check_ms_median']:.3f} ms median, {r['full_check_ms_p95']:.3f} ms p95  "
          f"(target < 2 ms: {'met' if r['full_check_ms_median'] < 2 else 'MISSED'})")
    print(f"checked samples per second (samples the sweep bound covers / check time): {r['checked_samples_per_s']:,.0f}")
    print(f"bare FK + TCP read over the {r['checked_samples']} sweep-bound samples: {r['bare_fk_tcp_us_median']:.0f} us -> ratio "
          f"{r['ratio_full_to_fk_tcp']:.2f}x (target <= 3x: {'met' if r['ratio_full_to_fk_tcp'] <= 3 else 'MISSED'})")
    print(f"bare FK + TCP read over the {r['evaluated_samples']} samples actually evaluated: "
          f"{r['bare_fk_tcp_evaluated_us_median']:.0f} us -> ratio {r['ratio_full_to_fk_tcp_evaluated']:.2f}x")
    print(f"bare FK + every checked body's placement: {r['bare_fk_bodies_us_median']:.0f} us -> ratio "
          f"{r['ratio_full_to_fk_bodies']:.2f}x")


# ------------------------------------------------------------------------------------ server
def _bench_policy_file(directory: Path) -> Path:
    """The bundled FR3 policy with rate limits raised so the benchmark measures latency, not limits."""
    import yaml

    document = yaml.safe_load(bundled_policy("fr3").read_text())
    document["rate_limits"] = {"global_per_minute": 1_000_000, "default_per_minute": 1_000_000, "per_tool": {}}
    path = directory / "bench-policy.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


#: calls per block when series are interleaved (the first few calls of each block are dropped)
BLOCK = 30


def _summary(values_s: list[float]) -> dict[str, float]:
    ms = [v * 1e3 for v in values_s]
    return {"median_ms": statistics.median(ms), "p95_ms": _percentile(ms, 95), "n": len(ms)}


async def _timed_calls(client, tool: str, args_for: Callable[[int], dict], repeats: int) -> list[float]:
    out = []
    for i in range(repeats):
        start = time.perf_counter()
        result = await client.call_tool(tool, args_for(i))
        out.append(time.perf_counter() - start)
        if result.is_error:
            raise RuntimeError(f"{tool} failed in the benchmark: {result.content[0].text}")
    return out[5:] if len(out) > 10 else out  # the first few calls warm caches up


def bench_server(repeats: int = 400) -> dict[str, Any]:
    """Round trips through the official SDK client. Series that are compared run interleaved, in
    blocks of `BLOCK` calls taken in turn, so machine drift hits every series alike while each
    block still measures warm, back-to-back calls."""
    import tempfile

    import anyio
    from mcp import Client, StdioServerParameters

    from armwarden.daemon import SWITCH_INTERVAL_S, assemble, close_assembly, open_assembly

    sys.setswitchinterval(SWITCH_INTERVAL_S)  # as `armwarden serve` runs
    sys.path.insert(0, str(TRIVIAL_SERVER.parent))
    # the SDK's own floor: constant tools, nothing of ArmWarden behind them
    trivial_server = importlib.import_module("trivial_server")

    results: dict[str, Any] = {}
    rounds = max(1, repeats // BLOCK)
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        policy_path = _bench_policy_file(directory)
        policy = load_policy(policy_path)

        def pose(i: int) -> dict:  # alternate between two nearby targets so every plan is a real one
            return {"position": {"x": 0.40 + 0.02 * (i % 2), "y": 0.05, "z": 0.35}}

        async def in_memory() -> dict[str, Any]:
            assembly = await open_assembly(*assemble(policy, "fake", None, str(directory / "audit.jsonl")))
            audit = assembly.guard.audit
            series: dict[str, list[float]] = {"audited": [], "unaudited": [], "shape": [], "trivial": []}
            out: dict[str, Any] = {}
            try:
                async with Client(assembly.server.mcp) as armwarden, Client(trivial_server.build()) as floor:
                    for _ in range(rounds):
                        assembly.guard.audit = audit
                        series["audited"] += await _timed_calls(armwarden, "get_robot_state", lambda i: {}, BLOCK)
                        assembly.guard.audit = None  # the same call with the audit record left out
                        series["unaudited"] += await _timed_calls(armwarden, "get_robot_state", lambda i: {}, BLOCK)
                        series["shape"] += await _timed_calls(floor, "robot_state_shape", lambda i: {}, BLOCK)
                        series["trivial"] += await _timed_calls(floor, "trivial", lambda i: {}, BLOCK)
                    assembly.guard.audit = audit
                    out = {name: _summary(values) for name, values in series.items()}
                    out["plan_to_pose"] = _summary(await _timed_calls(
                        armwarden, "plan_to_pose", lambda i: pose(i) | {"preview": False}, repeats))
                    out["plan_to_pose_with_preview"] = _summary(await _timed_calls(
                        armwarden, "plan_to_pose", pose, max(20, repeats // 10)))
            finally:
                assembly.guard.audit = audit
                await close_assembly(assembly, "benchmark done")
            return out

        memory = anyio.run(in_memory)
        results["plan_to_pose_in_memory"] = memory["plan_to_pose"]
        results["plan_to_pose_with_preview_in_memory"] = memory["plan_to_pose_with_preview"]
        results["get_robot_state_in_memory"] = memory["audited"]
        results["get_robot_state_in_memory_no_audit"] = memory["unaudited"]
        results["sdk_floor_state_shape_in_memory"] = memory["shape"]
        results["sdk_floor_in_memory"] = memory["trivial"]
        results["audit_overhead_per_call_ms"] = memory["audited"]["median_ms"] - memory["unaudited"]["median_ms"]

        async def over_stdio() -> dict[str, Any]:
            armwarden_params = StdioServerParameters(
                command=sys.executable,
                args=["-m", "armwarden.cli", "serve", "--policy", str(policy_path),
                      "--audit-log", str(directory / "stdio-audit.jsonl"), "--log-level", "WARNING"],
                env={"PYTHONPATH": str(SRC)},
            )
            floor_params = StdioServerParameters(command=sys.executable, args=[str(TRIVIAL_SERVER)])
            series: dict[str, list[float]] = {"armwarden": [], "shape": [], "trivial": []}
            async with Client(armwarden_params) as armwarden, Client(floor_params) as floor:
                for _ in range(rounds):
                    series["armwarden"] += await _timed_calls(armwarden, "get_robot_state", lambda i: {}, BLOCK)
                    series["shape"] += await _timed_calls(floor, "robot_state_shape", lambda i: {}, BLOCK)
                    series["trivial"] += await _timed_calls(floor, "trivial", lambda i: {}, BLOCK)
            return {name: _summary(values) for name, values in series.items()}

        stdio = anyio.run(over_stdio)
        results["get_robot_state_stdio"] = stdio["armwarden"]
        results["sdk_floor_state_shape_stdio"] = stdio["shape"]
        results["sdk_floor_stdio"] = stdio["trivial"]
        results["client_schema_validation_ms"] = _client_validation_ms(trivial_server.READY_STATE, trivial_server.build())
    return results


def _client_validation_ms(state: Any, server: Any, repeats: int = 2000) -> float:
    """Median cost of the SDK client's output-schema check for one `get_robot_state`-shaped result
    (the compiled jsonschema validator the client caches per tool, as `ClientSession` uses it)."""
    from jsonschema.validators import validator_for

    schema = server._tool_manager.get_tool("robot_state_shape").output_schema
    validator = validator_for(schema)(schema)
    instance = state.model_dump(mode="json")
    return statistics.median(_time_us(lambda: list(validator.iter_errors(instance)), repeats)) / 1e3


def _report_server(r: dict[str, Any]) -> None:
    def line(label: str, key: str, target: float | None = None) -> None:
        figures = r[key]
        verdict = "" if target is None else f"  (target <= {target:g} ms median: {'met' if figures['median_ms'] <= target else 'MISSED'})"
        print(f"{label}: {figures['median_ms']:.2f} ms median, {figures['p95_ms']:.2f} ms p95 over {figures['n']}{verdict}")

    print("## server (official MCP SDK client)")
    line("plan_to_pose round trip, in memory, all links checked, no preview", "plan_to_pose_in_memory", 5)
    line("plan_to_pose round trip, in memory, with the PNG preview (default)", "plan_to_pose_with_preview_in_memory")
    line("get_robot_state, in memory", "get_robot_state_in_memory", 1)
    line("get_robot_state over stdio", "get_robot_state_stdio", 1.5)
    line("get_robot_state, in memory, audit log off", "get_robot_state_in_memory_no_audit")
    print(f"audit record cost per call (difference of the interleaved medians; hash chain + fsync on the writer thread): "
          f"{r['audit_overhead_per_call_ms']:.2f} ms")
    line("SDK floor: trivial structured tool, in memory", "sdk_floor_in_memory")
    line("SDK floor: trivial structured tool, over stdio", "sdk_floor_stdio")
    line("SDK floor: constant result of get_robot_state's shape and schema, in memory", "sdk_floor_state_shape_in_memory")
    line("SDK floor: constant result of get_robot_state's shape and schema, over stdio", "sdk_floor_state_shape_stdio")
    print(f"  of which the SDK client re-validating that result against its output schema: "
          f"{r['client_schema_validation_ms']:.2f} ms")
    shape = r["sdk_floor_state_shape_in_memory"]["median_ms"]
    print(f"ArmWarden's own share of get_robot_state in memory (round trip - shape floor): "
          f"{r['get_robot_state_in_memory']['median_ms'] - shape:.2f} ms with the audit record, "
          f"{r['get_robot_state_in_memory_no_audit']['median_ms'] - shape:.2f} ms without")


# ------------------------------------------------------------------------------------ e-stop under load
def bench_estop(cycles: int = 60, load_clients: int = 8) -> dict[str, Any]:
    import os
    import signal
    import socket
    import subprocess
    import tempfile

    import anyio
    import httpx2
    import mcp_types as types
    from mcp import Client
    from mcp.client.streamable_http import streamable_http_client

    from armwarden.transport.tokens import TokenStore

    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        policy_path = _bench_policy_file(directory)
        token_file = directory / "tokens.json"
        token = TokenStore.add(token_file, "operator", "bench")
        audit_path = directory / "audit.jsonl"
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        env = dict(os.environ, PYTHONPATH=str(SRC))
        daemon = subprocess.Popen(
            [sys.executable, "-m", "armwarden.cli", "serve", "--transport", "http", "--host", "127.0.0.1",
             "--port", str(port), "--policy", str(policy_path), "--auth-tokens", str(token_file),
             "--audit-log", str(audit_path), "--log-level", "WARNING"],
            env=env, stdin=subprocess.DEVNULL,
        )
        url = f"http://127.0.0.1:{port}/mcp"
        load_calls = 0

        async def approve(context, params):
            return types.ElicitResult(action="accept", content={"approve": True, "operator": "bench"})

        def client(**kwargs):
            http = httpx2.AsyncClient(headers={"Authorization": f"Bearer {token}"}, timeout=30)
            return http, Client(streamable_http_client(url, http_client=http), **kwargs)

        async def wait_ready() -> None:
            async with httpx2.AsyncClient() as http:
                for _ in range(200):
                    try:
                        if (await http.get(f"http://127.0.0.1:{port}/healthz")).status_code == 200:
                            return
                    except httpx2.HTTPError:
                        pass
                    await anyio.sleep(0.05)
            raise RuntimeError("the daemon did not become ready")

        async def main() -> None:
            nonlocal load_calls
            await wait_ready()
            stop_load = anyio.Event()

            async def load() -> None:
                nonlocal load_calls
                http, c = client()
                async with http, c as session:
                    while not stop_load.is_set():
                        await session.call_tool("get_robot_state", {})
                        load_calls += 1

            async with anyio.create_task_group() as group:
                for _ in range(load_clients):
                    group.start_soon(load)
                http, c = client(elicitation_callback=approve)
                async with http, c as session:
                    home = (await session.call_tool("get_robot_state", {})).structured_content["joint_positions"]
                    for cycle in range(cycles):
                        status = (await session.call_tool("get_safety_status", {})).structured_content
                        if status["estopped"]:
                            await session.call_tool("reset_estop", {})
                        state = (await session.call_tool("get_robot_state", {})).structured_content["joint_positions"]
                        goal = list(home)
                        goal[0] = home[0] + (0.25 if state[0] <= home[0] else -0.25)
                        plan = await session.call_tool("plan_to_joints", {"joint_positions": goal, "preview": False})
                        plan_id = plan.structured_content["plan_id"]
                        async with anyio.create_task_group() as motion:
                            motion.start_soon(session.call_tool, "execute_plan", {"plan_id": plan_id})
                            await anyio.sleep(0.3)  # mid-motion
                            await session.call_tool("estop", {"reason": f"benchmark cycle {cycle}"})
                stop_load.set()

        try:
            anyio.run(main)
        finally:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=30)
        records = [json.loads(line) for line in audit_path.read_text().splitlines() if line.strip()]
    timings = [r["extra"]["stop_timing_ms"] for r in records
               if r.get("tool") == "estop" and "stop_timing_ms" in (r.get("extra") or {})]
    issued = [t["issued_after_receipt"] / 1e3 for t in timings]
    still = [t["still_after_receipt"] / 1e3 for t in timings if "still_after_receipt" in t]
    confirmed = [t["confirmed_after_receipt"] / 1e3 for t in timings]
    return {"estops": len(timings), "load_clients": load_clients, "load_calls": load_calls,
            "issued": _summary(issued), "still": _summary(still), "confirmed": _summary(confirmed)}


def _report_estop(r: dict[str, Any]) -> None:
    print(f"## e-stop under load ({r['load_clients']} HTTP clients calling get_robot_state, "
          f"{r['load_calls']} calls served during the run; {r['estops']} e-stops mid-motion)")
    for label, key, target in (
        ("request -> backend stop issued", "issued", 2.0),
        ("request -> arm still (hold published: no further position commanded)", "still", 2.0),
        ("request -> stop confirmation back on the event loop", "confirmed", None),
    ):
        f = r[key]
        verdict = "" if target is None else f"  (target <= {target:g} ms p95: {'met' if f['p95_ms'] <= target else 'MISSED'})"
        print(f"{label}: {f['median_ms']:.3f} ms median, {f['p95_ms']:.3f} ms p95{verdict}")


SECTIONS = {
    "envelope": (bench_envelope, _report_envelope),
    "server": (bench_server, _report_server),
    "estop": (bench_estop, _report_estop),
}


def main() -> int:
    import logging

    logging.basicConfig(level=logging.WARNING)  # the HTTP client logs every request at INFO
    for noisy in ("httpx", "httpx2", "mcp", "armwarden"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sections", nargs="*", help=f"any of {', '.join(SECTIONS)} (default: all)")
    parser.add_argument("--json", default=None, help="write the raw figures to this file")
    args = parser.parse_args()
    chosen = args.sections or list(SECTIONS)
    unknown = [name for name in chosen if name not in SECTIONS]
    if unknown:
        parser.error(f"unknown section(s) {unknown}; choose from {list(SECTIONS)}")
    results = {}
    for name in chosen:
        run, report = SECTIONS[name]
        results[name] = run()
        report(results[name])
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
