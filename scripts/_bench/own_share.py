"""ArmWarden's own share of a round trip, per transport (used by `scripts/bench.py share`).

For each transport — in memory, stdio, streamable HTTP under protocol 2025-11-25 ("legacy") and
2026-07-28 — two servers run side by side: ArmWarden (fake backend, the benchmark policy, audit
log on, HTTP with a bearer token) and the SDK floor (`trivial_server.py`: constant results of the
same model and output schema, captured from ArmWarden's own answers at the start, over the same
transport; over stdio a second time through ArmWarden's own stdio transport, which serves
stdin and stdout from the event loop where the SDK's hops to a thread per line: the first stdio
row is what a client pays above the SDK, the second what ArmWarden's tools and audit add on
their own). For `get_robot_state`, `get_safety_status`, `plan_to_pose` without and with the
preview picture, and `estop`, blocks of `BLOCK` calls alternate between the two servers, round
after round, so machine drift hits both alike; the own share is the difference of the medians.
After each round's e-stop block ArmWarden's latch is reset through an approved `reset_estop`
(the benchmark's client approves), so the next round plans again.

The preview's own cost is also measured apart: the renderer alone on a typical plan (p95), and
over stdio `plan_to_pose` with the preview against the same call without it.
"""

from __future__ import annotations

import gc
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from contextlib import AsyncExitStack, asynccontextmanager
from pathlib import Path
from typing import Any, cast

import numpy as np
from bench_common import (  # scripts/_bench is on sys.path (scripts/bench.py puts it there)
    approve_all,
    median_p95,
    stop_process,
    timed_calls,
)

HERE = Path(__file__).resolve().parent
SRC = HERE.parents[1] / "src"
TRIVIAL_SERVER = HERE / "trivial_server.py"
sys.path.insert(0, str(SRC))
sys.path.insert(0, str(HERE))

#: calls per block (the first `WARM` of each block are dropped: caches warm up after a switch)
BLOCK = 20
WARM = 3
#: (label, ArmWarden tool, its arguments for call i, floor tool)
CASES: tuple[tuple[str, str, Callable[[int], dict[str, Any]], str], ...] = (
    ("get_robot_state", "get_robot_state", lambda i: {}, "robot_state_shape"),
    ("get_safety_status", "get_safety_status", lambda i: {}, "get_safety_status_shape"),
    ("plan_to_pose, no preview", "plan_to_pose",
     lambda i: {"position": {"x": 0.40 + 0.02 * (i % 2), "y": 0.05, "z": 0.35}, "preview": False}, "plan_to_pose_shape"),
    ("plan_to_pose, with preview", "plan_to_pose",
     lambda i: {"position": {"x": 0.40 + 0.02 * (i % 2), "y": 0.05, "z": 0.35}}, "plan_to_pose_preview_shape"),
    ("estop", "estop", lambda i: {"reason": "benchmark"}, "estop_shape"),
)
#: the last one is the comparison with the audit log as it was before issue 13: every record,
#: also a state poll's, fsynced before its reply (`--audit-commit-window-ms 0`)
STRICT_AUDIT = "http 2026-07-28, fsync before every reply"
#: stdio again, the floor now served through ArmWarden's own stdio transport: what ArmWarden's
#: tools, middleware and audit add, with the transport's gain over the SDK's taken out
STDIO_SAME_TRANSPORT = "stdio, floor on ArmWarden's transport"
TRANSPORTS = ("memory", "stdio", STDIO_SAME_TRANSPORT, "http 2025-11-25", "http 2026-07-28", STRICT_AUDIT)
#: own-share targets [ms] for get_robot_state (issue 13)
TARGETS_MS = {"memory": 0.15, "stdio": 0.15, STDIO_SAME_TRANSPORT: 0.15, "http 2025-11-25": 0.5,
              "http 2026-07-28": 0.5}
RENDER_P95_TARGET_MS = 3.0
PREVIEW_RATIO_TARGET = 1.3


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _wait_listening(port: int, process: subprocess.Popen, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"server on port {port} exited with {process.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"nothing listens on port {port}")


async def _capture_shapes(armwarden: Any) -> dict[str, Any]:
    """The results ArmWarden really returns, for the floor to return as constants."""
    shapes: dict[str, Any] = {}
    for label, tool, args_for, _ in CASES:
        result = await armwarden.call_tool(tool, args_for(0))
        if result.is_error:
            raise RuntimeError(f"{tool} failed while capturing shapes: {result.content[0].text}")
        if label == "plan_to_pose, with preview":
            shapes["preview_png_b64"] = next(c.data for c in result.content if getattr(c, "type", "") == "image")
        else:
            shapes[tool] = result.structured_content
    await armwarden.call_tool("reset_estop", {})
    return shapes


async def _rounds(armwarden: Any, floor: Any, rounds: int) -> dict[str, dict[str, list[float]]]:
    series: dict[str, dict[str, list[float]]] = {label: {"armwarden": [], "floor": []} for label, *_ in CASES}
    for r in range(rounds):
        for label, tool, args_for, floor_tool in CASES:
            pair = [(armwarden, tool, args_for, "armwarden"), (floor, floor_tool, lambda i: {}, "floor")]
            if r % 2:
                pair.reverse()  # neither server always goes first
            for client, name, arguments, who in pair:
                series[label][who] += await timed_calls(client, name, arguments, BLOCK, warm=WARM)
        reset = await armwarden.call_tool("reset_estop", {})
        if reset.is_error:
            raise RuntimeError(f"reset_estop failed in the benchmark: {reset.content[0].text}")
    return series


@asynccontextmanager
async def _clients(transport: str, directory: Path, policy_path: Path, shapes_path: Path | None,
                   shapes: dict[str, Any] | None):
    """(ArmWarden client, floor client) over `transport`."""
    import trivial_server
    from mcp import Client, StdioServerParameters

    from armwarden.daemon.shutdown import close_assembly
    from armwarden.daemon.startup import assemble, open_assembly
    from armwarden.policy import load_policy

    async with AsyncExitStack() as stack:
        if transport == "memory":
            assembly = await open_assembly(assemble(load_policy(policy_path), "fake", None,
                                                     str(directory / "memory-audit.jsonl")))
            stack.push_async_callback(close_assembly, assembly, "benchmark done")
            armwarden = await stack.enter_async_context(Client(assembly.server.mcp, elicitation_callback=approve_all))
            floor = await stack.enter_async_context(Client(trivial_server.build(shapes)))
            yield armwarden, floor
            return
        floor_args = [sys.executable, str(TRIVIAL_SERVER)] + (["--shapes", str(shapes_path)] if shapes_path else [])
        env = {**os.environ, "PYTHONPATH": str(SRC)}
        if transport in ("stdio", STDIO_SAME_TRANSPORT):
            if transport == STDIO_SAME_TRANSPORT:
                floor_args.append("--armwarden-stdio")
            armwarden = await stack.enter_async_context(Client(StdioServerParameters(
                command=sys.executable, env={"PYTHONPATH": str(SRC)},
                args=["-m", "armwarden.cli", "serve", "--policy", str(policy_path),
                      "--audit-log", str(directory / "stdio-audit.jsonl"), "--log-level", "WARNING"],
            ), elicitation_callback=approve_all))
            floor = await stack.enter_async_context(Client(StdioServerParameters(
                command=floor_args[0], args=floor_args[1:], env={"PYTHONPATH": str(SRC)})))
            yield armwarden, floor
            return
        import httpx2
        from mcp.client.streamable_http import streamable_http_client

        from armwarden.transport.tokens import TokenStore

        mode = "legacy" if "2025-11-25" in transport else "2026-07-28"
        window = ["--audit-commit-window-ms", "0"] if transport == STRICT_AUDIT else []
        token_file = directory / f"tokens-{_free_port()}.json"  # one per daemon (a fresh number)
        token = TokenStore.add(token_file, "operator", "bench")
        aw_port, floor_port = _free_port(), _free_port()
        daemon = subprocess.Popen(  # noqa: ASYNC220 - set-up, before anything is timed
            [sys.executable, "-m", "armwarden.cli", "serve", "--transport", "http", "--host", "127.0.0.1",
             "--port", str(aw_port), "--policy", str(policy_path), "--auth-tokens", str(token_file),
             "--audit-log", str(directory / f"http-{mode}-{len(window)}-audit.jsonl"), "--log-level", "WARNING",
             *window],
            env=env, stdin=subprocess.DEVNULL)
        stack.callback(stop_process, daemon, 30)
        floor_process = subprocess.Popen(  # noqa: ASYNC220 - set-up, before anything is timed
            [*floor_args, "--http", str(floor_port)], env=env, stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        stack.callback(stop_process, floor_process, 30)
        _wait_listening(aw_port, daemon)
        _wait_listening(floor_port, floor_process)
        aw_http = await stack.enter_async_context(
            httpx2.AsyncClient(headers={"Authorization": f"Bearer {token}"}, timeout=60))
        floor_http = await stack.enter_async_context(httpx2.AsyncClient(timeout=60))
        armwarden = await stack.enter_async_context(Client(
            streamable_http_client(f"http://127.0.0.1:{aw_port}/mcp", http_client=aw_http),
            mode=mode, elicitation_callback=approve_all))
        floor = await stack.enter_async_context(Client(
            streamable_http_client(f"http://127.0.0.1:{floor_port}/mcp", http_client=floor_http), mode=mode))
        yield armwarden, floor


def _render_p95_ms(policy_path: Path, repeats: int = 300) -> dict[str, Any]:
    """The preview renderer alone, as the daemon runs it (one previewer per policy, the daemon's
    garbage-collector regime), on a typical 0.5 rad plan: p50 and p95 over `repeats` pictures."""
    from armwarden.assembly import plan_previewer
    from armwarden.daemon.startup import freeze_long_lived_objects
    from armwarden.policy import load_policy
    from armwarden.preflight import load_runtime_model

    runtime = load_runtime_model(load_policy(policy_path))
    ready = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
    goal = ready + np.array([0.5, 0.25, -0.2, 0.3, 0.2, -0.3, 0.4])
    trajectory = runtime.planner.plan_to_joints(ready, goal).trajectory
    if trajectory is None:
        raise RuntimeError("the benchmark's typical plan was not planned")
    report = runtime.envelope.check(trajectory)
    preview = plan_previewer()
    times, png = [], None
    # in the daemon's garbage-collector regime (`freeze_long_lived_objects` at start-up): this
    # process's own heap, grown by the transports measured before, must not lend the picture
    # collections that the daemon's frozen heap does not see
    threshold = gc.get_threshold()
    freeze_long_lived_objects()
    try:
        for _ in range(repeats):
            start = time.perf_counter()
            png = preview(runtime, trajectory, report)
            times.append(time.perf_counter() - start)
    finally:
        gc.unfreeze()
        gc.set_threshold(*threshold)
    assert png is not None
    out: dict[str, Any] = {**median_p95(times[10:]), "png_bytes": len(png)}
    library = _library_share_ms(lambda: preview(runtime, trajectory, report), repeats)
    # Pinocchio's calls go through Boost.Python, which cProfile does not see: its forward
    # kinematics for the picture (the swept poses and the thinned TCP path) is timed apart
    from armwarden.preview.render import MAX_PATH_POINTS, SWEEP_SAMPLES

    robot, positions = runtime.robot, np.asarray(trajectory.positions)
    swept = np.vstack([trajectory.sample(t) for t in np.linspace(0.0, trajectory.duration_s, SWEEP_SAMPLES)])
    path = positions[np.linspace(0, len(positions) - 1, MAX_PATH_POINTS).round().astype(int)]
    kinematics = []
    for _ in range(repeats):
        start = time.perf_counter()
        robot.joint_frames(swept)
        robot.tcp_points(path)
        kinematics.append(time.perf_counter() - start)
    library["forward kinematics"] = float(np.median(kinematics)) * 1e3
    out["library_ms"] = library
    return out


#: the libraries' calls a picture cannot do without, by the name cProfile gives them
LIBRARY_CALLS = {
    "zlib": ("zlib.Compress", "zlib.adler32"),  # deflating the changed row bands (compress, flush), their checksum
    "strokes": ("ImagingDraw",),  # Pillow's line, ellipse, rectangle and polygon primitives
}


def _library_share_ms(render: Callable[[], Any], repeats: int) -> dict[str, float]:
    """Per picture, the time spent inside the C calls of zlib and of Pillow's drawing primitives
    (cProfile's own time of those calls, which its overhead barely touches): with forward
    kinematics, the floor of drawing this picture with these libraries."""
    import cProfile
    import pstats

    profile = cProfile.Profile()
    profile.enable()
    for _ in range(repeats):
        render()
    profile.disable()
    stats = cast("dict[tuple[str, int, str], tuple[Any, ...]]", pstats.Stats(profile).stats)  # type: ignore[attr-defined]
    share = dict.fromkeys(LIBRARY_CALLS, 0.0)
    for (filename, _, name), (_, _, own_s, _, _) in stats.items():
        where = f"{filename} {name}"
        for library, markers in LIBRARY_CALLS.items():
            if any(marker in where for marker in markers):
                share[library] += own_s
    return {library: seconds / repeats * 1e3 for library, seconds in share.items()}


def bench_own_share(policy_path: Path, directory: Path, rounds: int = 6) -> dict[str, Any]:
    import anyio

    from armwarden.daemon.startup import SWITCH_INTERVAL_S

    sys.setswitchinterval(SWITCH_INTERVAL_S)  # as `armwarden serve` runs
    results: dict[str, Any] = {"transports": {}}
    shapes_path = directory / "shapes.json"
    shapes: dict[str, Any] | None = None
    for transport in TRANSPORTS:
        async def run(transport: str = transport) -> dict[str, dict[str, list[float]]]:
            nonlocal shapes
            if shapes is None:  # capture once, from ArmWarden in memory, before any floor is built
                async with _clients("memory", directory, policy_path, None, None) as (armwarden, _):
                    shapes = await _capture_shapes(armwarden)
                shapes_path.write_text(json.dumps(shapes))
            async with _clients(transport, directory, policy_path, shapes_path, shapes) as (armwarden, floor):
                await timed_calls(armwarden, "get_robot_state", lambda i: {}, BLOCK, warm=WARM)  # warm both up
                await timed_calls(floor, "robot_state_shape", lambda i: {}, BLOCK, warm=WARM)
                return await _rounds(armwarden, floor, rounds)

        series = anyio.run(run)
        figures = {}
        for label, pair in series.items():
            aw, fl = median_p95(pair["armwarden"]), median_p95(pair["floor"])
            figures[label] = {"armwarden": aw, "floor": fl, "own_ms": aw["median_ms"] - fl["median_ms"],
                              "own_p95_ms": aw["p95_ms"] - fl["p95_ms"]}
        results["transports"][transport] = figures
    results["raw_stdio"] = _raw_stdio_round_trips(policy_path, directory)
    results["render"] = _render_p95_ms(policy_path)
    stdio = results["transports"]["stdio"]
    results["preview_ratio_stdio"] = (stdio["plan_to_pose, with preview"]["armwarden"]["median_ms"]
                                      / stdio["plan_to_pose, no preview"]["armwarden"]["median_ms"])
    return results


#: the three servers of the raw stdio comparison: (label, command after the interpreter, tool)
RAW_SERVERS = (
    ("SDK floor (the SDK's stdio transport)", [str(TRIVIAL_SERVER)], "robot_state_shape"),
    ("floor on ArmWarden's stdio transport", [str(TRIVIAL_SERVER), "--armwarden-stdio"], "robot_state_shape"),
    ("ArmWarden", None, "get_robot_state"),
)


def _raw_stdio_round_trips(policy_path: Path, directory: Path, calls: int = 4000, rounds: int = 20) -> dict[str, Any]:
    """`get_robot_state` (and the floor's constant of its shape) over stdio from a bare JSON-RPC
    client — one line out, one line back, nothing else in the client — so the servers' side of a
    round trip is seen without the SDK client's own cost (≈ 0.8 ms of Python per call). Blocks of
    calls alternate between the servers; also each server's CPU time per call (user + system,
    from /proc)."""
    servers = []
    for label, args, tool in RAW_SERVERS:
        command = [sys.executable, *(args or ["-m", "armwarden.cli", "serve", "--policy", str(policy_path),
                                              "--audit-log", str(directory / "raw-stdio-audit.jsonl"),
                                              "--log-level", "WARNING"])]
        process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                   env={**os.environ, "PYTHONPATH": str(SRC)})
        servers.append((label, process, tool))
    per_block = calls // rounds
    times: dict[str, list[float]] = {label: [] for label, _, _ in servers}
    cpu = dict.fromkeys(times, 0.0)
    try:
        for _, process, tool in servers:
            _raw_call(process, "initialize", {"protocolVersion": "2025-11-25", "capabilities": {},
                                              "clientInfo": {"name": "raw-bench", "version": "1"}})
            _raw_send(process, {"jsonrpc": "2.0", "method": "notifications/initialized"})
            for _ in range(WARM):
                _raw_call(process, "tools/call", {"name": tool, "arguments": {}})
        for r in range(rounds):
            for label, process, tool in servers if r % 2 == 0 else servers[::-1]:
                before = _cpu_s(process)
                for i in range(per_block):
                    start = time.perf_counter()
                    _raw_call(process, "tools/call", {"name": tool, "arguments": {}})
                    if i >= WARM:
                        times[label].append(time.perf_counter() - start)
                cpu[label] += _cpu_s(process) - before
    finally:
        for _, process, _ in servers:
            stop_process(process, 30)
    return {label: {**median_p95(series), "cpu_ms": cpu[label] / (rounds * per_block) * 1e3}
            for label, series in times.items()}


def _raw_send(process: subprocess.Popen, message: dict[str, Any]) -> None:
    assert process.stdin is not None
    process.stdin.write(json.dumps(message).encode() + b"\n")
    process.stdin.flush()


def _raw_call(process: subprocess.Popen, method: str, params: dict[str, Any]) -> None:
    assert process.stdout is not None
    _raw_send(process, {"jsonrpc": "2.0", "id": 1, "method": method, "params": params})
    answer = process.stdout.readline()
    if not answer or b'"isError":true' in answer or b'"error"' in answer[:40]:
        raise RuntimeError(f"{method} failed in the raw stdio benchmark: {answer[:300]!r}")


def _cpu_s(process: subprocess.Popen) -> float:
    """The process's user + system CPU time [s] (Linux /proc; 0 elsewhere)."""
    try:
        fields = Path(f"/proc/{process.pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def report_own_share(r: dict[str, Any]) -> None:
    print("## own share per transport (ArmWarden round trip - SDK floor of the same result shape, same transport;")
    print(f"## interleaved blocks of {BLOCK} calls, medians; audit log on; HTTP with a bearer token)")
    print("| transport | call | SDK floor | ArmWarden | own share | target |")
    print("|---|---|---|---|---|---|")
    for transport, figures in r["transports"].items():
        for label, f in figures.items():
            target = ""
            if label == "get_robot_state" and transport in TARGETS_MS:
                goal = TARGETS_MS[transport]
                target = f"≤ {goal:g} ms: {'met' if f['own_ms'] <= goal else 'MISSED'}"
            print(f"| {transport} | {label} | {f['floor']['median_ms']:.2f} ms (p95 {f['floor']['p95_ms']:.2f}) "
                  f"| {f['armwarden']['median_ms']:.2f} ms (p95 {f['armwarden']['p95_ms']:.2f}) "
                  f"| {f['own_ms']:.2f} ms | {target} |")
    raw = r["raw_stdio"]
    print("## get_robot_state over stdio from a bare JSON-RPC client (the servers' side of a round trip)")
    print("| server | round trip, median | p95 | CPU per call |")
    print("|---|---|---|---|")
    for label, f in raw.items():
        print(f"| {label} | {f['median_ms']:.3f} ms | {f['p95_ms']:.3f} ms | {f['cpu_ms']:.3f} ms |")
    render = r["render"]
    print(f"preview picture alone (typical 0.5 rad plan, {render['png_bytes']} bytes): {render['median_ms']:.2f} ms median, "
          f"{render['p95_ms']:.2f} ms p95 (target ≤ {RENDER_P95_TARGET_MS:g} ms p95: "
          f"{'met' if render['p95_ms'] <= RENDER_P95_TARGET_MS else 'MISSED'})")
    library = render["library_ms"]
    floor = sum(library.values())
    print("  of which inside the libraries (the floor of this picture): "
          + ", ".join(f"{name} {ms:.2f} ms" for name, ms in library.items())
          + f"; together {floor:.2f} ms; ArmWarden's own work above that floor {render['median_ms'] - floor:.2f} ms")
    ratio = r["preview_ratio_stdio"]
    stdio = r["transports"]["stdio"]
    budget = (PREVIEW_RATIO_TARGET - 1.0) * stdio["plan_to_pose, no preview"]["armwarden"]["median_ms"]
    carried = (stdio["plan_to_pose, with preview"]["floor"]["median_ms"]
               - stdio["plan_to_pose, no preview"]["floor"]["median_ms"])
    print(f"plan_to_pose over stdio, with preview / without: {ratio:.2f}x (target ≤ {PREVIEW_RATIO_TARGET:g}x: "
          f"{'met' if ratio <= PREVIEW_RATIO_TARGET else 'MISSED'}); the target leaves {budget:.2f} ms for the picture, "
          f"of which the SDK's carrying it takes {carried:.2f} ms and the libraries' floor {floor:.2f} ms"
          + (f": the target lies {carried + floor - budget:.2f} ms below that floor" if carried + floor > budget else ""))


__all__ = ["bench_own_share", "report_own_share"]
