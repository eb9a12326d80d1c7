"""`.venv-ros/bin/python scripts/bench.py ros2`: the ROS 2 backend against the fake FR3 cell.

One process, as `armwarden serve --backend ros2 --backend-config examples/ros2_fr3.yaml`
assembles it (the daemon's switch interval and garbage-collector settings), with the fake cell
(`tests_ros.cell.Cell`, real rclpy endpoints in a context and executor of its own) IN THIS
PROCESS, so that its positions can be sampled directly; both share one interpreter lock, which
makes every figure here an upper bound of what a separate cell process would show. Needs the ROS
venv (rclpy and the built interfaces; see scripts/test.sh). DDS stays on this host: a random
ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless both are already set.

Over `runs` runs (default 100), each an approved `execute_plan` of a joint move interrupted by an
`estop` call once the motion is under way (followed by an approved `reset_estop`):

- goal sent → accepted: the backend's `send_goal_async` call → its goal response (accepted)
  handled in the backend's executor;
- e-stop request → goal cancel sent: the `estop` call sent by the SDK client (in memory) → the
  backend's `cancel_goal_async` call;
- cancel → cell stopped: that cancel call → the cell's joint positions still (the last change of
  the cell's positions, sampled every 0.2 ms; 0 when the cell did not move again after the
  cancel was sent) and → the backend receiving the goal's result (the cell's action server has
  finished the goal: it holds position);
- `get_robot_state` round trips on ros2 and on the fake, interleaved in blocks in the same run.

The times come from class-level hooks on rclpy's `ActionClient`/`ClientGoalHandle` in this
process (the cell is a server, so every client call is the backend's), on `time.perf_counter`.
"""

from __future__ import annotations

import os
import random
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

# scripts/_bench is on sys.path (scripts/bench.py puts it there)
from bench_common import approve_all, bench_policy, percentiles, stop_process, timed_ms

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "ros2_fr3.yaml"
BLOCK = 20
#: fraction of the motion after which the e-stop is sent
ESTOP_AT_PROGRESS = 0.3


def _percentiles(values: list[float]) -> dict[str, float]:
    return percentiles(values, (50, 99))


class ActionTimes:
    """Hooks on rclpy's action client classes that stamp each goal sent and accepted, each cancel
    sent and each result received (`time.perf_counter`), for the one goal in flight."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.reset()

    def reset(self) -> None:
        with self.lock:
            self.goal_sent: float | None = None
            self.goal_accepted: float | None = None
            self.cancel_sent: float | None = None
            self.result: float | None = None

    def install(self) -> None:
        from rclpy.action.client import ActionClient, ClientGoalHandle

        times = self
        send_goal_async = ActionClient.send_goal_async
        cancel_goal_async = ClientGoalHandle.cancel_goal_async
        get_result_async = ClientGoalHandle.get_result_async

        def on_send_goal(client: Any, *args: Any, **kwargs: Any) -> Any:
            sent = time.perf_counter()
            future = send_goal_async(client, *args, **kwargs)
            with times.lock:
                times.goal_sent = sent

            def accepted(done: Any) -> None:
                stamp = time.perf_counter()
                if done.result() is not None and done.result().accepted:
                    with times.lock:
                        times.goal_accepted = stamp

            future.add_done_callback(accepted)
            return future

        def on_cancel(handle: Any, *args: Any, **kwargs: Any) -> Any:
            stamp = time.perf_counter()
            with times.lock:
                if times.cancel_sent is None:
                    times.cancel_sent = stamp
            return cancel_goal_async(handle, *args, **kwargs)

        def on_get_result(handle: Any, *args: Any, **kwargs: Any) -> Any:
            future = get_result_async(handle, *args, **kwargs)

            def received(_done: Any) -> None:
                stamp = time.perf_counter()
                with times.lock:
                    times.result = stamp

            future.add_done_callback(received)
            return future

        for owner, name, hook in ((ActionClient, "send_goal_async", on_send_goal),
                                  (ClientGoalHandle, "cancel_goal_async", on_cancel),
                                  (ClientGoalHandle, "get_result_async", on_get_result)):
            setattr(owner, name, hook)


class StillWatch:
    """A thread that samples the cell's joint positions every 0.2 ms and keeps the time of their
    last change (`time.perf_counter`)."""

    def __init__(self, cell: Any) -> None:
        self.cell = cell
        self.last_change = time.perf_counter()
        self._done = False
        self._thread = threading.Thread(target=self._run, name="bench-still-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        previous = self.cell.positions()
        while not self._done:
            now = time.perf_counter()
            current = self.cell.positions()
            if not np.array_equal(current, previous):
                self.last_change, previous = now, current
            time.sleep(0.0002)

    def close(self) -> None:
        self._done = True
        self._thread.join(1.0)


def _local_dds() -> None:
    """The network rule: a random domain and localhost-only discovery, unless both are set."""
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != "LOCALHOST" or "ROS_DOMAIN_ID" not in os.environ:
        os.environ["ROS_DOMAIN_ID"] = str(random.randint(1, 100))
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)


def bench_ros2(runs: int = 100, state_calls: int = 200) -> dict[str, Any]:
    _local_dds()
    sys.path.insert(0, str(ROOT))  # tests_ros.cell
    import anyio
    from mcp import Client
    from tests_ros.cell import Cell

    from armwarden.daemon.shutdown import close_assembly
    from armwarden.daemon.startup import SWITCH_INTERVAL_S, assemble, freeze_long_lived_objects, open_assembly

    sys.setswitchinterval(SWITCH_INTERVAL_S)
    policy = bench_policy()

    times = ActionTimes()
    times.install()

    async def run(directory: Path) -> dict[str, Any]:
        out: dict[str, Any] = {"runs": runs, "domain_id": int(os.environ["ROS_DOMAIN_ID"])}
        with Cell() as cell:
            fake = await open_assembly(assemble(policy, "fake", None, str(directory / "fake-audit.jsonl")))
            ros = await open_assembly(assemble(policy, "ros2", str(EXAMPLE), str(directory / "ros2-audit.jsonl")))
            freeze_long_lived_objects()
            watch = StillWatch(cell)
            try:
                async with Client(fake.server.mcp) as on_fake, Client(ros.server.mcp, elicitation_callback=approve_all) as on_ros:
                    # ---- get_robot_state on both backends, interleaved in blocks
                    series: dict[str, list[float]] = {"state_fake": [], "state_ros2": []}
                    for _ in range(max(1, state_calls // BLOCK)):
                        for _ in range(BLOCK):
                            series["state_fake"].append(await timed_ms(on_fake, "get_robot_state", {}))
                            series["state_ros2"].append(await timed_ms(on_ros, "get_robot_state", {}))
                    out["state_ms"] = {name: _percentiles(values) for name, values in series.items()}

                    # ---- execute, e-stop mid-motion, reset
                    figures: dict[str, list[float]] = {"accepted_ms": [], "estop_to_cancel_ms": [],
                                                       "cancel_to_still_ms": [], "cancel_to_result_ms": []}
                    missed: list[str] = []
                    for index in range(runs):
                        state = (await on_ros.call_tool("get_robot_state", {})).structured_content
                        q = state["joint_positions"]
                        goal = [q[0] + (0.2 if index % 2 == 0 else -0.2), *q[1:]]
                        planned = await on_ros.call_tool("plan_to_joints", {"joint_positions": goal, "velocity_scaling": 0.3,
                                                                            "preview": False})
                        assert not planned.is_error, planned.content
                        plan_id = planned.structured_content["plan_id"]
                        times.reset()
                        moving: dict[str, Any] = {}
                        requested = 0.0  # when the estop call is sent

                        async def execute(plan_id: str = plan_id, holder: dict[str, Any] = moving) -> None:
                            holder["result"] = await on_ros.call_tool("execute_plan", {"plan_id": plan_id})

                        async with anyio.create_task_group() as motion:
                            motion.start_soon(execute)
                            while ros.guard.motion_status().progress < ESTOP_AT_PROGRESS:  # noqa: ASYNC110 - moved by the executor thread
                                await anyio.sleep(0.002)
                            requested = time.perf_counter()
                            await on_ros.call_tool("estop", {"reason": "bench"})
                        deadline = time.perf_counter() + 3.0
                        while time.perf_counter() < deadline and (  # noqa: ASYNC110 - stamped by the executor threads
                                times.result is None or time.perf_counter() - watch.last_change < 0.3):
                            await anyio.sleep(0.01)
                        sent, accepted, cancel, result = times.goal_sent, times.goal_accepted, times.cancel_sent, times.result
                        if sent is None or accepted is None or cancel is None or result is None:
                            missed.append(f"run {index}: sent {sent}, accepted {accepted}, cancel {cancel}, result {result}")
                        else:
                            figures["accepted_ms"].append((accepted - sent) * 1e3)
                            figures["estop_to_cancel_ms"].append((cancel - requested) * 1e3)
                            figures["cancel_to_still_ms"].append(max(0.0, watch.last_change - cancel) * 1e3)
                            figures["cancel_to_result_ms"].append((result - cancel) * 1e3)
                        reset = await on_ros.call_tool("reset_estop", {})
                        assert not reset.is_error, reset.content
                    out.update({name: _percentiles(values) for name, values in figures.items()})
                    out["missed"] = missed
            finally:
                watch.close()
                await close_assembly(ros, "benchmark done")
                await close_assembly(fake, "benchmark done")
        return out

    with tempfile.TemporaryDirectory() as tmp:
        return anyio.run(run, Path(tmp))


def bench_executors(seconds: float = 10.0) -> dict[str, Any]:
    """The backend's executor, single- vs multi-threaded: with the cell in ANOTHER process
    (`python -m tests_ros.cell`), an open backend only receives (joint states and fingers at
    100 Hz, the wrench at 100 Hz) for `seconds` per kind; measured: this process's CPU time and
    the gaps between joint-state receipts (publisher period 10 ms)."""
    import resource
    import subprocess

    import anyio
    import rclpy.executors

    sys.path.insert(0, str(ROOT))  # tests_ros
    from tests_ros.backend_setup import POLICY, ROBOT, example_config

    from armwarden.backends.ros2.backend import create_backend

    kinds = {
        "single-threaded (the backend's)": rclpy.executors.SingleThreadedExecutor,
        "multi-threaded, 4 threads": lambda context: rclpy.executors.MultiThreadedExecutor(num_threads=4, context=context),
    }

    async def receive(factory: Any) -> dict[str, Any]:
        backend = create_backend(ROBOT, POLICY, example_config(), executor_factory=factory)
        await backend.open()
        try:
            gaps: list[float] = []
            last = backend.joint_states.latest()
            before = resource.getrusage(resource.RUSAGE_SELF)
            started = time.monotonic()
            while time.monotonic() - started < seconds:
                await anyio.sleep(0.001)
                state = backend.joint_states.latest()
                if state is not None and last is not None and state.stamp != last.stamp:
                    gaps.append((state.stamp - last.stamp) * 1e3)
                last = state
            after = resource.getrusage(resource.RUSAGE_SELF)
            elapsed = time.monotonic() - started
        finally:
            await backend.close()
        cpu = (after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime) / elapsed
        return {"cpu_percent": 100.0 * cpu, "received_hz": len(gaps) / elapsed, "gap_ms": percentiles(gaps, (50, 99))}

    cell = subprocess.Popen([sys.executable, "-m", "tests_ros.cell"], cwd=ROOT, stdout=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        time.sleep(2.0)  # the cell's endpoints up; the backend's open waits for the first joint state anyway
        return {"seconds": seconds, "kinds": {name: anyio.run(receive, factory) for name, factory in kinds.items()}}
    finally:
        stop_process(cell, 5.0)


def report_executors(r: dict[str, Any]) -> None:
    print(f"### the backend's executor (cell in another process, {r['seconds']:g} s per kind)")
    print("| executor | process CPU [%] | joint states received [Hz] | receipt gap p50 / p99 / max [ms] |")
    print("|---|---|---|---|")
    for name, f in r["kinds"].items():
        g = f["gap_ms"]
        print(f"| {name} | {f['cpu_percent']:.0f} | {f['received_hz']:.0f} | {g['p50']:.1f} / {g['p99']:.1f} / {g['max']:.1f} |")


def report_ros2(r: dict[str, Any]) -> None:
    print("## ros2 (the fake FR3 cell in this process, real rclpy endpoints on a localhost-only DDS domain; "
          "SDK client in memory)")
    rows = (
        ("execute_plan: goal sent -> accepted (at the backend)", "accepted_ms"),
        ("e-stop request -> goal cancel sent", "estop_to_cancel_ms"),
        ("cancel sent -> cell positions still", "cancel_to_still_ms"),
        ("cancel sent -> goal result at the backend", "cancel_to_result_ms"),
    )
    print(f"over {r['runs']} runs (each: execute, e-stop at {ESTOP_AT_PROGRESS:.0%} of the motion, reset):")
    print("| measure | p50 [ms] | p99 [ms] | max [ms] | n |")
    print("|---|---|---|---|---|")
    for label, key in rows:
        f = r[key]
        print(f"| {label} | {f['p50']:.2f} | {f['p99']:.2f} | {f['max']:.2f} | {f['n']} |")
    fake, ros = r["state_ms"]["state_fake"], r["state_ms"]["state_ros2"]
    print(f"| get_robot_state round trip, ros2 | {ros['p50']:.2f} | {ros['p99']:.2f} | {ros['max']:.2f} | {ros['n']} |")
    print(f"| get_robot_state round trip, fake | {fake['p50']:.2f} | {fake['p99']:.2f} | {fake['max']:.2f} | {fake['n']} |")
    print(f"get_robot_state ros2 / fake, ratio of medians: {ros['p50'] / fake['p50']:.2f}, of p99s: {ros['p99'] / fake['p99']:.2f}")
    if r["missed"]:
        print(f"runs without a complete set of stamps: {len(r['missed'])}: " + "; ".join(r["missed"][:5]))
