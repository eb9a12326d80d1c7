"""`python scripts/bench.py flood`: the stop channel under the outside review's flood (issue 24).

For each backend — the fake, and ROS 2 against the fake cell when .venv-ros exists — one daemon,
`armwarden serve --transport http --estop-port … --auth-tokens …` on 127.0.0.1 as a subprocess
(through `stop_trace.py`, which stamps the channel's stop path and logs garbage collections), and
a session of the official SDK client opened before anything else (bench.py is this measuring
process). Then, in two phases — idle, then under the flood — the same cycle, `stops` times:

  get_robot_state; plan_to_joints 0.2 rad of joint 1 from home and back (no preview); execute_plan
  (approved by this process's elicitation callback) and, once its first progress above 0 arrives
  (the arm is moving), one ``POST /estop`` to the stop channel, stamped step by step
  (`bench_common.timed_estop_post`), then a byte through a bare echo thread in the daemon's
  process (its floor: needs the interpreter lock and a core, does nothing else); the execution's
  answer; reset_estop (approved), so that the next stop finds the latch released.

The flood is `flood.py` in its own process: 16 SDK clients over streamable HTTP (8 planners —
plan_to_pose and plan_to_joints in turn, half with the PNG preview — and 8 get_robot_state
readers, each in a loop) plus 100 slow sockets on the MCP port and 40 on the stop channel's
(half silent, half sending a request head a byte every 2 s; reopened when closed): the review's
load. It ramps up (≤ 20 s), the cycles run, then it is told to end (SIGTERM) and reports what it
achieved. Every loop is bounded in count and time; everything is on 127.0.0.1.

On ROS 2 the cell runs as a process of its own (`flood_cell.py`: `python -m tests_ros.cell`
with its goals' ends stamped), on a random ROS_DOMAIN_ID with discovery on localhost only, and
the figure is POST → arm still: the cell's trajectory loop ends the cancelled goal and stops
moving the arm (it moves it every 10 ms). The policy and backend config are the ones the ROS 2
daemon tests use (wrench and joint-state ages 0.5 s and 1 s instead of 0.1 s and 0.5 s: a Python
cell on this loaded 2-core host publishes with gaps above 0.1 s, and the force monitor would
rightly abort the motion before the stop).

Where the time goes, per stop (`stop_trace.py` stamps in the daemon, on the clock the sender
shares): connect and send (this side); request sent → request read by the channel thread;
read → stop issued (`latch_and_stop`: latch, backend stop); issued → answer out; answer out →
answer read here. The channel thread's time on a core and waiting for one
(/proc/…/schedstat) splits the daemon's intervals; the rest is time asleep: waiting for the
interpreter lock (the request was there to read) or for the backend's locks. Also: the
daemon's threads' CPU and run-queue wait over each phase, garbage collections overlapping
stops, the host's load average.
"""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# scripts/_bench is on sys.path (scripts/bench.py puts it there)
from bench_common import approve_all, stop_process, timed_estop_post

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
ROS_PYTHON = ROOT / ".venv-ros" / "bin" / "python"
HOST = "127.0.0.1"  # never anything else

#: flood.py --mix: planners readers cameras movers churners — the review's 16 clients doing reads and plans
CLIENT_MIX = (8, 8, 0, 0, 0)
SLOW_MCP, SLOW_CHANNEL = 100, 40
#: e-stops per phase (the idle phase too: its figure stands beside the flood's)
STOPS = 200
#: bounds on one phase's cycles [s]; the flood process ends on its own this much later at the latest
PHASE_LIMIT_S = 480.0
FLOOD_MARGIN_S = 60.0
#: bound on one cycle's motion: execute_plan answered after its stop [s]
CYCLE_LIMIT_S = 60.0
GOAL_STEP_RAD = 0.2
MOTION = {"velocity_scaling": 0.1, "preview": False}
#: slow stops, whose breakdown is printed one by one: above this many ms from POST to answer
SLOW_STOP_MS = 20.0


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind((HOST, 0))
        return probe.getsockname()[1]


def _summary(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    array = np.asarray(values, dtype=float)
    return {"n": len(values), **{f"p{q}": float(np.percentile(array, q)) for q in (50, 95, 99)}, "max": float(array.max())}


# ------------------------------------------------------------------------------------ processes
@dataclass
class Daemon:
    """The daemon under test, its ports and the files its wrapper writes."""

    process: subprocess.Popen[bytes]
    port: int
    estop_port: int
    echo_port: int
    files: dict[str, Path]
    cell: subprocess.Popen[str] | None = None


def _ros_environment() -> dict[str, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(1, 100)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("ROS_STATIC_PEERS", None)
    return env


def _ros_files(policy_path: Path, directory: Path) -> tuple[Path, Path]:
    """The policy and examples/ros2_fr3.yaml with the ROS 2 daemon tests' ages (module docstring)."""
    import yaml

    from armwarden.policy import apply_overrides
    from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S

    policy = directory / "ros2-policy.yaml"
    policy.write_text(yaml.safe_dump(apply_overrides(yaml.safe_load(policy_path.read_text()),
                                                     {"force.wrench_timeout_s": MAX_WRENCH_TIMEOUT_S})))
    config = directory / "ros2_fr3.yaml"
    config.write_text(yaml.safe_dump(apply_overrides(yaml.safe_load((ROOT / "examples" / "ros2_fr3.yaml").read_text()),
                                                     {"wrench.max_age_s": MAX_WRENCH_TIMEOUT_S, "joint_states.max_age_s": 1.0})))
    return policy, config


def start_daemon(backend: str, policy_path: Path, directory: Path, tokens: Path, experiment: dict[str, str]) -> Daemon:
    """The daemon (and on ros2 the cell first) with `tokens`, the stop channel and the wrappers' logs."""
    files = {name: directory / f"{backend}-{name}" for name in ("audit.jsonl", "gc.jsonl", "stops.jsonl", "threads.json",
                                                                "daemon.err", "cell.jsonl")}
    port, estop_port, echo_port = free_port(), free_port(), free_port()
    env = dict(os.environ)
    python, extra = sys.executable, []
    cell = None
    if backend == "ros2":
        env = _ros_environment()
        python = str(ROS_PYTHON)
        policy_path, config = _ros_files(policy_path, directory)
        extra = ["--backend", "ros2", "--backend-config", str(config)]
        cell = subprocess.Popen([python, str(HERE / "flood_cell.py")], cwd=ROOT, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, text=True,
                                env={**env, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
                                     "ARMWARDEN_BENCH_CELL_LOG": str(files["cell.jsonl"])})
        assert cell.stdout is not None
        line = cell.stdout.readline()
        if "fake FR3 cell ready" not in line:
            stop_process(cell, 10)
            raise RuntimeError(f"the fake cell did not start: {line!r}")
    env.update(PYTHONPATH=str(ROOT / "src"), ARMWARDEN_BENCH_GC_LOG=str(files["gc.jsonl"]),
               ARMWARDEN_BENCH_STOP_LOG=str(files["stops.jsonl"]), ARMWARDEN_BENCH_THREADS=str(files["threads.json"]),
               ARMWARDEN_BENCH_ECHO_PORT=str(echo_port), **experiment)
    try:
        with open(files["daemon.err"], "wb") as stderr:
            process = subprocess.Popen(
                [python, str(HERE / "stop_trace.py"), "serve", "--transport", "http", "--host", HOST, "--port", str(port),
                 "--estop-port", str(estop_port), "--policy", str(policy_path), "--auth-tokens", str(tokens),
                 "--audit-log", str(files["audit.jsonl"]), "--log-level", "WARNING", *extra],
                env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=stderr,
            )
    except BaseException:
        if cell is not None:
            stop_process(cell, 15)
        raise
    return Daemon(process, port, estop_port, echo_port, files, cell)


def stop_daemon(daemon: Daemon) -> None:
    stop_process(daemon.process, 30)
    if daemon.cell is not None:
        stop_process(daemon.cell, 15)


def start_flood(daemon: Daemon, token_file: Path, home: list[float], out: Path, duration_s: float) -> subprocess.Popen[str]:
    flood = subprocess.Popen(
        [sys.executable, str(HERE / "flood.py"), "--mcp-port", str(daemon.port), "--estop-port", str(daemon.estop_port),
         "--token-file", str(token_file), "--home", *map(str, home), "--duration", str(duration_s), "--out", str(out),
         "--mix", *map(str, CLIENT_MIX), "--slow-mcp", str(SLOW_MCP), "--slow-channel", str(SLOW_CHANNEL)],
        env=dict(os.environ), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True,
    )
    assert flood.stdout is not None
    line = flood.stdout.readline()  # "ready" once every client made its first call (or the ramp-up is over)
    if not line.startswith("ready"):
        stop_process(flood, 10)
        raise RuntimeError(f"the flood did not start: {line!r}")
    return flood


# ------------------------------------------------------------------------------------ /proc
def thread_times(pid: int) -> dict[str, tuple[float, float]]:
    """{tid: (CPU time, run-queue wait) [s]} of every thread of `pid` (Linux /proc)."""
    out = {}
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            waiting = int((task / "schedstat").read_text().split()[1]) / 1e9
        except (OSError, IndexError, ValueError):
            continue
        out[task.name] = ((int(fields[11]) + int(fields[12])) / tick, waiting)
    return out


def process_cpu_s(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def echo_ms(port: int) -> float | None:
    """One byte through the bare echo thread in the daemon's process (`gc_watch._echo`) [ms]."""
    start = time.monotonic()
    try:
        with socket.create_connection((HOST, port), timeout=2.0) as echo:
            echo.sendall(b"!")
            echo.recv(1)
    except OSError:
        return None
    return (time.monotonic() - start) * 1e3


# ------------------------------------------------------------------------------------ the cycles
@dataclass
class Phase:
    """One phase's stops as the sender saw them, and what the machine did meanwhile."""

    name: str
    stops: list[dict[str, Any]] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    started: float = 0.0
    ended: float = 0.0
    load_average: list[float] = field(default_factory=list)
    threads_before: dict[str, tuple[float, float]] = field(default_factory=dict)
    threads_after: dict[str, tuple[float, float]] = field(default_factory=dict)
    cpu: dict[str, float] = field(default_factory=dict)


async def run_cycles(session: Any, daemon: Daemon, token: str, home: list[float], phase: Phase, count: int,
                     flood_pid: int | None) -> None:
    import anyio

    phase.load_average.append(os.getloadavg()[0])
    phase.threads_before = thread_times(daemon.process.pid)
    cpu_before = {"daemon": process_cpu_s(daemon.process.pid), "measuring": time.process_time()}
    if flood_pid is not None:
        cpu_before["flood"] = process_cpu_s(flood_pid)
    if daemon.cell is not None:
        cpu_before["cell"] = process_cpu_s(daemon.cell.pid)
    phase.started = time.monotonic()
    deadline = phase.started + PHASE_LIMIT_S
    for index in range(count):
        if time.monotonic() > deadline:
            phase.failures.append(f"phase limit of {PHASE_LIMIT_S:g} s reached after {index} stops")
            break
        state = await session.call_tool("get_robot_state", {})
        if state.is_error:
            phase.failures.append(f"get_robot_state: {state.content}")
            await anyio.sleep(0.2)
            continue
        q = state.structured_content["joint_positions"]
        goal = [home[0] + (GOAL_STEP_RAD if q[0] <= home[0] else -GOAL_STEP_RAD), *home[1:]]
        plan = await session.call_tool("plan_to_joints", {"joint_positions": goal, **MOTION})
        if plan.is_error or plan.structured_content.get("plan_id") is None:
            phase.failures.append(f"plan_to_joints: {plan.content}")
            continue
        moving = anyio.Event()
        answer: dict[str, Any] = {}

        async def on_progress(progress: float, total: float | None, message: str | None, moving: Any = moving) -> None:
            if progress > 0:
                moving.set()

        async def execute(plan_id: str = plan.structured_content["plan_id"], answer: dict[str, Any] = answer) -> None:
            answer["result"] = await session.call_tool("execute_plan", {"plan_id": plan_id}, progress_callback=on_progress)

        record: dict[str, Any] = {"index": index, "moving": False}
        with anyio.move_on_after(CYCLE_LIMIT_S) as bounded:
            async with anyio.create_task_group() as motion:
                motion.start_soon(execute)
                with anyio.move_on_after(10.0):
                    await moving.wait()
                record["moving"] = moving.is_set()
                try:
                    # on this thread, blocking it for the one request: no thread hop, no interpreter lock
                    # shared with this loop's other work, in the stamped part
                    record.update(timed_estop_post(daemon.estop_port, token, f"bench {phase.name} {index}"))
                except RuntimeError as exc:
                    phase.failures.append(f"stop {index}: {exc}")
                record["echo_ms"] = echo_ms(daemon.echo_port)
        if bounded.cancelled_caught:
            phase.failures.append(f"cycle {index}: no answer to execute_plan within {CYCLE_LIMIT_S:g} s (cancelled)")
        result = answer.get("result")
        record["execution"] = None if result is None else (
            "refused" if result.is_error else (result.structured_content or {}).get("status"))
        phase.stops.append(record)
        for _ in range(3):  # release the latch (a human approves: here the callback)
            reset = await session.call_tool("reset_estop", {})
            if not reset.is_error:
                break
            phase.failures.append(f"reset_estop refused: {reset.content}")
    phase.ended = time.monotonic()
    phase.threads_after = thread_times(daemon.process.pid)
    wall = phase.ended - phase.started
    phase.cpu = {"daemon": (process_cpu_s(daemon.process.pid) - cpu_before["daemon"]) / wall,
                 "measuring": (time.process_time() - cpu_before["measuring"]) / wall}
    if flood_pid is not None:
        phase.cpu["flood"] = (process_cpu_s(flood_pid) - cpu_before["flood"]) / wall
    if daemon.cell is not None:
        phase.cpu["cell"] = (process_cpu_s(daemon.cell.pid) - cpu_before["cell"]) / wall
    phase.load_average.append(os.getloadavg()[0])


async def _wait_healthy(daemon: Daemon, timeout_s: float = 60.0) -> None:
    import anyio
    import httpx2

    deadline = time.monotonic() + timeout_s
    async with httpx2.AsyncClient() as http:
        while time.monotonic() < deadline and daemon.process.poll() is None:
            try:
                if (await http.get(f"http://{HOST}:{daemon.port}/healthz")).status_code == 200:
                    return
            except httpx2.HTTPError:
                pass
            await anyio.sleep(0.1)
    raise RuntimeError(f"the daemon did not become ready: {daemon.files['daemon.err'].read_text()[-2000:]}")


def bench_backend(backend: str, policy_path: Path, directory: Path, stops: int, experiment: dict[str, str]) -> dict[str, Any]:
    """Idle, then flooded: `stops` e-stops each on one daemon of `backend` (module docstring)."""
    import anyio
    import httpx2
    from mcp import Client
    from mcp.client.streamable_http import streamable_http_client

    from armwarden.transport.tokens import TokenStore

    tokens = directory / f"{backend}-tokens.json"
    token = TokenStore.add(tokens, "operator", "bench")  # printed once: the file keeps its hash only
    daemon = start_daemon(backend, policy_path, directory, tokens, experiment)
    token_file = directory / f"{backend}-operator.token"  # for flood.py: not on its command line
    token_file.touch(mode=0o600)
    token_file.write_text(token, encoding="utf-8")
    idle, flooded = Phase("idle"), Phase("flood")
    flood: subprocess.Popen[str] | None = None
    flood_out = directory / f"{backend}-flood.json"

    async def main() -> None:
        nonlocal flood
        await _wait_healthy(daemon)
        http = httpx2.AsyncClient(headers={"Authorization": f"Bearer {token}"}, timeout=60)
        async with http, Client(streamable_http_client(f"http://{HOST}:{daemon.port}/mcp", http_client=http),
                                elicitation_callback=approve_all) as session:
            home = (await session.call_tool("get_robot_state", {})).structured_content["joint_positions"]
            await run_cycles(session, daemon, token, home, idle, stops, None)
            flood = await anyio.to_thread.run_sync(
                lambda: start_flood(daemon, token_file, home, flood_out, PHASE_LIMIT_S + FLOOD_MARGIN_S))
            await anyio.sleep(1.0)  # the flood's first second is its own
            await run_cycles(session, daemon, token, home, flooded, stops, flood.pid)

    try:
        anyio.run(main)
        if flood is not None:
            flood.send_signal(signal.SIGTERM)  # ends its window; it reports and exits
            flood.wait(timeout=60)
    finally:
        if flood is not None:
            stop_process(flood, 10)
        stop_daemon(daemon)
    return _figures(backend, daemon, idle, flooded, flood_out, experiment)


# ------------------------------------------------------------------------------------ the figures
def _read_lines(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _split(before: list[float], after: list[float], start: float | None = None) -> dict[str, float]:
    """An interval of the channel thread between two of its stamps [t, cpu, run-queue wait] in ms:
    wall (from `start` when given), on a core, waiting for one, and asleep (the rest)."""
    wall = after[0] - (before[0] if start is None else max(start, before[0]))
    cpu, queued = after[1] - before[1], after[2] - before[2]
    return {"wall": wall * 1e3, "cpu": cpu * 1e3, "queued": queued * 1e3, "asleep": max(0.0, wall - cpu - queued) * 1e3}


def _breakdown(stop: dict[str, Any], trace: dict[str, Any]) -> dict[str, Any]:
    """Where one stop's time went: the sender's stamps and the channel thread's (module docstring)."""
    sent = stop["sent"]
    # The channel thread's last stamp at or before the request was sent. When it is a select's start,
    # the thread slept in select until the request came: its CPU and run-queue deltas from there are
    # this wait's. When it is a select's return, the thread was busy with other sockets' work when the
    # request came: the deltas (and the wall time, for the split) run from that return.
    starts = [(r[0], r[:3], True) for r in trace["rounds"]]
    returns = [(r[3], r[3:], False) for r in trace["rounds"]]
    earlier = [s for s in starts + returns if s[0] <= sent]
    _, base, in_select = max(earlier, key=lambda s: s[0]) if earlier else (0.0, trace["read"], False)
    to_read = _split(base, trace["read"], start=sent if in_select else None)
    to_read["wall"] = (trace["read"][0] - sent) * 1e3  # the stop's own wait, whatever the thread did before
    rounds_after = sum(1 for r in trace["rounds"] if sent < r[3] <= trace["read"][0])
    return {
        "total": (stop["done"] - stop["start"]) * 1e3,
        "connect": (stop["connected"] - stop["start"]) * 1e3,
        "send": (stop["sent"] - stop["connected"]) * 1e3,
        "to_read": to_read,
        "busy_when_sent": not in_select,
        "rounds": rounds_after,
        "to_latch": _split(trace["read"], trace["latch"]),
        "stop": _split(trace["latch"], trace["issued"]),
        "to_answer": _split(trace["issued"], trace["answering"]),
        "answer_to_sender": (stop["answered"] - trace["answering"][0]) * 1e3,  # send(), the sender's wake-up
        "after_send": _split(trace["answering"], trace["answered"]),  # the channel thread, back from send()
        "read_answer": (stop["done"] - stop["answered"]) * 1e3,
    }


def _annotate(phase: Phase, traces: dict[int, dict[str, Any]], cell: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each answered stop with its figures [ms]: POST -> answer, the daemon's and the sender's
    parts of it, its breakdown, the variant of an alternating experiment, and on ROS 2 the cell's."""
    done = [s for s in phase.stops if "done" in s]
    bounds = [s["start"] for s in done] + [phase.ended]
    out = []
    for stop, following in zip(done, bounds[1:], strict=True):
        row: dict[str, Any] = {"post_to_answer": (stop["done"] - stop["start"]) * 1e3, "echo": stop.get("echo_ms"),
                               "server_issued": stop.get("stop_issued_ms")}
        trace = traces.get(stop["event"])
        if trace is not None:
            b = row["breakdown"] = _breakdown(stop, trace)
            row["variant"] = trace.get("variant")
            row["daemon_side"] = (trace["answering"][0] - stop["sent"]) * 1e3  # request sent -> answer's send()
            row["sender_side"] = row["post_to_answer"] - row["daemon_side"]
            row["busy_when_sent"] = b["busy_when_sent"]
        if cell:  # the cell's first cancel and first cancelled goal after this POST, before the next one
            cancel = next((e["t"] for e in cell if e["kind"] == "cancel_received" and stop["start"] <= e["t"] < following), None)
            still = next((e["t"] for e in cell if e["kind"] == "canceled" and stop["start"] <= e["t"] < following), None)
            row["cell_cancel"] = None if cancel is None else (cancel - stop["start"]) * 1e3
            row["arm_still"] = None if still is None else (still - stop["start"]) * 1e3
            if cancel is not None and still is not None and trace is not None:
                row["issued_to_cell_cancel"] = (cancel - trace["issued"][0]) * 1e3  # DDS and the cell's executor
                row["cell_cancel_to_still"] = (still - cancel) * 1e3  # the cell's 10 ms trajectory loop
        out.append(row)
    return out


def _column(rows: list[dict[str, Any]], key: str) -> dict[str, float]:
    return _summary([r[key] for r in rows if r.get(key) is not None])


def _phase_figures(phase: Phase, traces: dict[int, dict[str, Any]], cell: list[dict[str, Any]],
                   pauses: list[dict[str, Any]], names: dict[str, str]) -> dict[str, Any]:
    rows = _annotate(phase, traces, cell)
    headline = ("post_to_answer", "daemon_side", "sender_side", "server_issued", "echo") + (
        ("cell_cancel", "arm_still", "issued_to_cell_cancel", "cell_cancel_to_still") if cell else ())
    figures: dict[str, Any] = {
        "stops": len(phase.stops), "answered": len(rows), "moving": sum(1 for s in phase.stops if s["moving"]),
        "executions": {str(k): sum(1 for s in phase.stops if s["execution"] == k) for k in {s["execution"] for s in phase.stops}},
        "failures": phase.failures, "seconds": phase.ended - phase.started, "load_average": phase.load_average,
        "cpu_cores": phase.cpu,
        "ms": {key: _column(rows, key) for key in headline},
    }
    variants = sorted({r["variant"] for r in rows if r.get("variant") is not None})
    if len(variants) > 1:
        figures["by_variant"] = {str(v): {key: _column([r for r in rows if r.get("variant") == v], key) for key in headline}
                                 for v in variants}
    breakdowns = [r["breakdown"] for r in rows if "breakdown" in r]
    if breakdowns:
        def series(key: str, part: str | None = None) -> dict[str, float]:
            return _summary([b[key] if part is None else b[key][part] for b in breakdowns])

        figures["breakdown_ms"] = {
            "connect": series("connect"), "send": series("send"),
            **{f"to_read.{part}": series("to_read", part) for part in ("wall", "cpu", "queued", "asleep")},
            **{f"{key}.{part}": series(key, part)
               for key in ("to_latch", "stop", "to_answer", "after_send") for part in ("wall", "asleep", "queued")},
            "answer_to_sender": series("answer_to_sender"), "read_answer": series("read_answer"),
        }
        slow = sorted((b for b in breakdowns if b["total"] > SLOW_STOP_MS), key=lambda b: -b["total"])
        figures["slow_stops"] = [_slow_stop(b) for b in slow]
        # the channel thread from the request sent to the answer's send(), summed over the stops
        totals = {part: sum(b[key][part] for key in ("to_read", "to_latch", "stop", "to_answer") for b in breakdowns)
                  for part in ("cpu", "queued", "asleep")}
        figures["channel_thread_share"] = {part: value / sum(totals.values()) for part, value in totals.items()}
        figures["busy_when_sent"] = sum(1 for b in breakdowns if b["busy_when_sent"])
    inside = [p for p in pauses if phase.started <= p["start"] <= phase.ended]
    done = [s for s in phase.stops if "done" in s]
    overlapping = [s for s in done if any(p["start"] < s["done"] and p["start"] + p["ms"] / 1e3 > s["start"] for p in inside)]
    figures["gc"] = {"collections_logged": len(inside), "full": sum(1 for p in inside if p["gen"] == 2),
                     "longest_ms": max((p["ms"] for p in inside), default=0.0), "total_ms": sum(p["ms"] for p in inside),
                     "stops_overlapping": len(overlapping),
                     "slow_stops_overlapping": sum(1 for s in overlapping if (s["done"] - s["start"]) * 1e3 > SLOW_STOP_MS)}
    figures["threads"] = _thread_figures(phase, names)
    figures["rows"] = rows
    return figures


def _slow_stop(b: dict[str, Any]) -> dict[str, float]:
    return {"total": b["total"], "connect": b["connect"], "send": b["send"], "to_read": b["to_read"]["wall"],
            "to_read_queued": b["to_read"]["queued"], "to_read_asleep": b["to_read"]["asleep"], "to_read_cpu": b["to_read"]["cpu"],
            "rounds": b["rounds"], "read_to_issued": b["to_latch"]["wall"] + b["stop"]["wall"],
            "to_answer": b["to_answer"]["wall"], "answer_to_sender": b["answer_to_sender"]}


def _thread_figures(phase: Phase, names: dict[str, str]) -> list[dict[str, Any]]:
    """The daemon's threads by CPU over the phase: cores used, run-queue wait per second of wall."""
    wall = phase.ended - phase.started
    merged: dict[str, dict[str, float]] = {}
    for tid, (cpu, waiting) in phase.threads_after.items():
        cpu0, waiting0 = phase.threads_before.get(tid, (0.0, 0.0))
        name = names.get(tid, "threads not named (rclpy's, DDS's)")
        if name.startswith("AnyIO worker"):  # the planner's and the SDK's worker threads come and go
            name = "AnyIO worker threads"
        entry = merged.setdefault(name, {"cores": 0.0, "queued_per_s": 0.0, "threads": 0})
        entry["cores"] += (cpu - cpu0) / wall
        entry["queued_per_s"] += (waiting - waiting0) / wall
        entry["threads"] += 1
    return sorted(({"thread": k, **v} for k, v in merged.items()), key=lambda r: -r["cores"])


def _figures(backend: str, daemon: Daemon, idle: Phase, flooded: Phase, flood_out: Path,
             experiment: dict[str, str]) -> dict[str, Any]:
    traces = {t["event"]: t for t in _read_lines(daemon.files["stops.jsonl"]) if t.get("event") is not None}
    cell = sorted(_read_lines(daemon.files["cell.jsonl"]), key=lambda e: e["t"])
    pauses = [p for p in _read_lines(daemon.files["gc.jsonl"]) if "ms" in p]
    names = json.loads(daemon.files["threads.json"].read_text()) if daemon.files["threads.json"].exists() else {}
    return {
        "backend": backend,
        "experiment": experiment,
        "idle": _phase_figures(idle, traces, cell, pauses, names),
        "flood": _phase_figures(flooded, traces, cell, pauses, names),
        "load": json.loads(flood_out.read_text()) if flood_out.exists() else {},
        "uptime": subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip(),
        "raw": {"idle": idle.stops, "flood": flooded.stops},
    }


def bench_stop_flood(policy_path: Path, *, stops: int = STOPS, backends: tuple[str, ...] = ("fake", "ros2"),
                     switch_interval_s: float | None = None, alternate: str | None = None) -> dict[str, Any]:
    """Every backend of `backends` that can run here (ros2 needs .venv-ros), one after the other.
    `switch_interval_s` and `alternate` are experiments (`stop_trace.py`)."""
    experiment = {}
    if switch_interval_s is not None:
        experiment["ARMWARDEN_BENCH_SWITCH_INTERVAL_S"] = str(switch_interval_s)
    if alternate is not None:
        experiment["ARMWARDEN_BENCH_ALTERNATE"] = alternate
    out: dict[str, Any] = {"stops": stops, "backends": {}, "skipped": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for backend in backends:
            if backend == "ros2" and not ROS_PYTHON.exists():
                out["skipped"][backend] = f"{ROS_PYTHON} is missing (scripts/test.sh builds it)"
                continue
            out["backends"][backend] = bench_backend(backend, policy_path, Path(tmp), stops, experiment)
    return out


# ------------------------------------------------------------------------------------ the report
LABELS = {
    "post_to_answer": "POST -> answer (sender's round trip)",
    "daemon_side": "  of which the daemon: request sent -> answer's send()",
    "sender_side": "  of which the sender: connect, send, wake-up, read",
    "server_issued": "request read -> stop issued (the channel's stop_issued_ms)",
    "cell_cancel": "POST -> cancel received at the cell",
    "arm_still": "POST -> arm still at the cell",
    "issued_to_cell_cancel": "  stop issued (daemon) -> cancel received at the cell",
    "cell_cancel_to_still": "  cancel received -> arm still (the cell's 10 ms loop)",
    "echo": "floor: a byte through a bare thread in the daemon",
}


def _row(label: str, f: dict[str, float]) -> str:
    if not f.get("n"):
        return f"| {label} | - | - | - | - | 0 |"
    return f"| {label} | {f['p50']:.2f} | {f['p95']:.2f} | {f['p99']:.2f} | {f['max']:.2f} | {f['n']} |"


def report_stop_flood(r: dict[str, Any]) -> None:
    print(f"## stop channel under the review's flood ({CLIENT_MIX[0]} planners + {CLIENT_MIX[1]} readers = "
          f"{sum(CLIENT_MIX)} MCP clients, {SLOW_MCP} slow sockets on the MCP port, {SLOW_CHANNEL} on the channel; "
          f"{r['stops']} e-stops per phase)")
    for backend, why in r["skipped"].items():
        print(f"{backend}: skipped ({why})")
    for backend, b in r["backends"].items():
        _report_backend(backend, b)


def _report_backend(backend: str, b: dict[str, Any]) -> None:
    idle, flood, load = b["idle"], b["flood"], b["load"]
    experiment = f", experiment {b['experiment']}" if b["experiment"] else ""
    print(f"### {backend}{experiment}   ({b['uptime']})")
    if load:
        print(f"flood: {load['clients_started']}/{load['clients']} clients up; calls/s answered: "
              + ", ".join(f"{kind} {rate:.1f}" for kind, rate in load["calls_per_s"].items())
              + f"; failed: {load['failed'] or 'none'}; slow sockets held: "
              + ", ".join(f"{name} median {held['median']:g}" for name, held in load["slow_held"].items())
              + f"; closed by the server: {load['slow_closed_by_server'] or 'none'}")
    for name, phase in (("idle", idle), ("flood", flood)):
        print(f"{name}: {phase['answered']}/{phase['stops']} stops answered, {phase['moving']} hit a moving arm, "
              f"executions {phase['executions']}, {phase['seconds']:.0f} s; 1-min load average "
              f"{' -> '.join(f'{v:.2f}' for v in phase['load_average'])}; cores used: "
              + ", ".join(f"{k} {v:.2f}" for k, v in phase["cpu_cores"].items())
              + (f"; failures: {phase['failures'][:3]}" if phase["failures"] else ""))
    print("| ms | p50 | p95 | p99 | max | n |")
    print("|---|---|---|---|---|---|")
    for name, phase in (("idle", idle), ("flood", flood)):
        for key, f in phase["ms"].items():
            print(_row(f"{name}: {LABELS[key]}", f))
    for name, phase in (("idle", idle), ("flood", flood)):
        for variant, figures in phase.get("by_variant", {}).items():
            for key in ("post_to_answer", "daemon_side", "server_issued", "arm_still"):
                if key in figures:
                    print(_row(f"{name}, variant {variant}: {LABELS[key]}", figures[key]))
    for name, phase in (("idle", idle), ("flood", flood)):
        if "breakdown_ms" not in phase:
            continue
        print(f"where a stop's time goes, {name} (channel thread: cpu = on a core, queued = runnable, waiting "
              "for a core, asleep = the rest: waiting for the interpreter lock or a backend lock)")
        print("| ms | p50 | p95 | p99 | max | n |")
        print("|---|---|---|---|---|---|")
        for key, f in phase["breakdown_ms"].items():
            print(_row(key, f))
        share = phase["channel_thread_share"]
        print(f"channel thread, request sent -> answer's send(), summed over the stops: {share['cpu']:.0%} on a core, "
              f"{share['queued']:.0%} waiting for a core, {share['asleep']:.0%} asleep (interpreter lock, locks); "
              f"the thread was awake, not in select, when the request was sent (other sockets, or accepting this "
              f"one): {phase['busy_when_sent']} stops")
        for s in phase["slow_stops"][:5]:
            print("  slow stop: " + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in s.items()))
        gc = phase["gc"]
        print(f"garbage collections logged (full or > 2 ms): {gc['collections_logged']} ({gc['full']} full), longest "
              f"{gc['longest_ms']:.1f} ms, {gc['total_ms']:.0f} ms in all; stops overlapping one: "
              f"{gc['stops_overlapping']} ({gc['slow_stops_overlapping']} of those > {SLOW_STOP_MS:g} ms)")
        print("daemon threads (cores used / run-queue wait per second): " + "; ".join(
            f"{t['thread']} {t['cores']:.2f} / {t['queued_per_s']:.2f}" for t in phase["threads"][:8]))
