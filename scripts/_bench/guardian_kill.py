"""`python scripts/bench.py guardian`: the ROS 2 daemon killed (SIGKILL) mid-motion, `runs` times
(default 20), each on a daemon and a fake FR3 cell process of its own (`stop_flood.start_daemon`:
the cell is `flood_cell.py`, which stamps its action server's cancel callback and each goal's end on
CLOCK_MONOTONIC, the clock this process reads when it kills the daemon).

Per run: an approved slow joint move (about 10 s) starts; once the first progress arrives the daemon
gets SIGKILL. Nothing of the daemon runs after that; its guardian process (issue "The arm stays
safe when the server does not") sees the pipe close and cancels the goal. Figures: kill → the
cell's cancel callback, kill → the goal ended (the cell's arm still from then on), p50 / p95 / max
[ms], and how each goal ended (canceled: the guardian stopped it; succeed: it ran to its end).
Needs the ROS venv; DDS on this host only (a random ROS_DOMAIN_ID, localhost discovery).
"""

from __future__ import annotations

import contextlib
import json
import tempfile
import time
from pathlib import Path
from typing import Any

# scripts/_bench is on sys.path (scripts/bench.py puts it there)
from bench_common import approve_all, percentiles
from stop_flood import HOST, _wait_healthy, start_daemon, stop_daemon

#: how far joint 1 moves [rad], and how slowly: about 10 s of motion, long enough to interrupt
STEP_RAD = 0.3
SLOW = {"velocity_scaling": 0.03, "acceleration_scaling": 0.03, "preview": False}
#: how long a run waits for the cell to end the goal after the kill [s]
END_TIMEOUT_S = 15.0


def _cell_events(path: Path, after: float) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    lines = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    return [line for line in lines if line["t"] >= after]


def _one_run(policy_path: Path, directory: Path) -> dict[str, Any]:
    import anyio
    import httpx2
    from mcp import Client
    from mcp.client.streamable_http import streamable_http_client

    from armwarden.transport.tokens import TokenStore

    directory.mkdir(parents=True)
    tokens = directory / "tokens.json"
    token = TokenStore.add(tokens, "operator", "bench")
    daemon = start_daemon("ros2", policy_path, directory, tokens, {})
    killed: dict[str, float] = {}

    async def main() -> None:
        await _wait_healthy(daemon)
        http = httpx2.AsyncClient(headers={"Authorization": f"Bearer {token}"}, timeout=60)
        moving = anyio.Event()

        async def on_progress(progress: float, total: float | None, message: str | None) -> None:
            moving.set()

        async with http, Client(streamable_http_client(f"http://{HOST}:{daemon.port}/mcp", http_client=http),
                                elicitation_callback=approve_all) as session:
            home = (await session.call_tool("get_robot_state", {})).structured_content["joint_positions"]
            goal = [home[0] + STEP_RAD, *home[1:]]
            plan = (await session.call_tool("plan_to_joints", {"joint_positions": goal, **SLOW})).structured_content
            with anyio.fail_after(60):
                async with anyio.create_task_group() as group:
                    async def execute() -> None:
                        with contextlib.suppress(Exception):  # the daemon dies under the call
                            await session.call_tool("execute_plan", {"plan_id": plan["plan_id"]},
                                                    progress_callback=on_progress)

                    group.start_soon(execute)
                    await moving.wait()
                    killed["t"] = time.monotonic()
                    daemon.process.kill()
                    await anyio.to_thread.run_sync(daemon.process.wait)
                    group.cancel_scope.cancel()

    try:
        anyio.run(main)
        deadline = time.monotonic() + END_TIMEOUT_S
        events: list[dict[str, Any]] = []
        while time.monotonic() < deadline:
            events = _cell_events(daemon.files["cell.jsonl"], killed["t"])
            if any(e["kind"] != "cancel_received" for e in events):
                break
            time.sleep(0.05)
    finally:
        stop_daemon(daemon)
    cancel = next((e["t"] for e in events if e["kind"] == "cancel_received"), None)
    end = next((e for e in events if e["kind"] != "cancel_received"), None)
    return {"cancel_ms": None if cancel is None else (cancel - killed["t"]) * 1000.0,
            "end_ms": None if end is None else (end["t"] - killed["t"]) * 1000.0,
            "ended": "none" if end is None else end["kind"]}


def bench_guardian(policy_path: Path, runs: int = 20) -> dict[str, Any]:
    """`runs` kills, each on a daemon and cell of its own (module docstring); `policy_path`: the
    bench's FR3 policy file."""
    with tempfile.TemporaryDirectory(prefix="armwarden-bench-guardian-") as tmp:
        results = [_one_run(policy_path, Path(tmp) / f"run{i}") for i in range(runs)]
    cancels = [r["cancel_ms"] for r in results if r["cancel_ms"] is not None]
    ends = [r["end_ms"] for r in results if r["end_ms"] is not None]
    endings: dict[str, int] = {}
    for r in results:
        endings[r["ended"]] = endings.get(r["ended"], 0) + 1
    return {"runs": runs, "endings": endings,
            "kill_to_cancel_ms": percentiles(cancels), "kill_to_still_ms": percentiles(ends)}


def report_guardian(r: dict[str, Any]) -> None:
    print(f"\n== guardian: ROS 2 daemon killed (SIGKILL) mid-motion, {r['runs']} runs")
    print(f"goals ended: {r['endings']}")
    for key, label in (("kill_to_cancel_ms", "kill -> cancel at the cell"), ("kill_to_still_ms", "kill -> cell's arm still")):
        f = r[key]
        print(f"{label}: n {f['n']}, p50 {f['p50']:.1f} ms, p95 {f['p95']:.1f} ms, max {f['max']:.1f} ms")
