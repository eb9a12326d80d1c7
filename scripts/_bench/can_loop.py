"""`python scripts/bench.py can`: the CAN servo loop while the server handles calls.

One process, as `armwarden serve --backend can --backend-config examples/can_sim.yaml` assembles
it (the daemon's switch interval and garbage-collector settings), with the 7 emulated RobStride
actuators on python-can's in-process virtual bus (the emulator on its own thread; kernel vcan is
not available here). For each control rate (500 Hz, 1 kHz), for `seconds` each, while one SDK
client in memory keeps the server busy (`get_robot_state` + `plan_to_pose` in a loop, and a small
executed move every few loops), the run measures

- the servo loop's achieved tick rate, deadline-miss rate (a tick that began more than one period
  after it was scheduled; goal < 0.5 % at 1 kHz) and p99 period jitter (|interval − period|),
  from the loop's own `ServoLoop.timing` histogram;
- e-stop latency: the `estop` tool call sent → the first damping frame (kp = 0, kd > 0) on the
  bus, as stamped by the virtual bus when it was sent and by a listener bus when it arrived
  (goal ≤ one control period), p50/p99; each e-stop is followed by an approved `reset_estop`.
"""

from __future__ import annotations

import logging
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from bench_stats import percentiles  # scripts/_bench is on sys.path (scripts/bench.py puts it there)

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "can_sim.yaml"
RATES_HZ = (500, 1000)
#: time between two e-stops [s] (each followed by a reset)
ESTOP_EVERY_S = 1.0


def _percentiles(values: list[float]) -> dict[str, float]:
    return percentiles(values, (50, 99))


class DampingWatch:
    """A listener on the virtual channel: notes the first damping command frame after `arm()`,
    with the bus's send stamp (`time.time`) and its own arrival stamp."""

    def __init__(self, channel: str, ranges: dict[int, Any]) -> None:
        import can

        self._ranges = ranges
        self._bus = can.Bus(interface="virtual", channel=channel)
        self.armed_after: float | None = None
        self.found: tuple[float, float] | None = None  # (sent on the bus, arrived here), time.time
        self._notifier = can.Notifier(self._bus, [self._on], timeout=0.05)
        self._lock = threading.Lock()

    def arm(self, after: float) -> None:
        with self._lock:
            self.found, self.armed_after = None, after

    def _on(self, msg: Any) -> None:
        from armwarden.backends.can import robstride as rs

        arrived = time.time()
        after = self.armed_after
        if after is None or self.found is not None or msg.is_error_frame or not msg.is_extended_id:
            return
        if rs.split_id(msg.arbitration_id).comm_type != rs.CommType.CONTROL:
            return
        motor = msg.arbitration_id & 0xFF
        if motor not in self._ranges:
            return  # not an actuator of this arm
        command = rs.unpack_control(msg.arbitration_id, bytes(msg.data), self._ranges[motor])[1]
        if command.kp == 0.0 and command.kd > 0.0 and msg.timestamp >= after:
            with self._lock:
                if self.found is None:
                    self.found = (msg.timestamp, arrived)

    def close(self) -> None:
        self._notifier.stop()
        self._bus.shutdown()


def _config_file(directory: Path, rate_hz: int) -> Path:
    import yaml

    document = yaml.safe_load(EXAMPLE.read_text())
    document["bus"]["channel"] = f"armwarden-bench-{uuid.uuid4().hex}"
    document["control_rate_hz"] = rate_hz
    path = directory / f"can-{rate_hz}.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def bench_can(seconds: float = 60.0, rates_hz: tuple[int, ...] = RATES_HZ) -> dict[str, Any]:
    import anyio
    import mcp_types as types
    from mcp import Client

    from armwarden.daemon import SWITCH_INTERVAL_S, assemble, close_assembly, freeze_long_lived_objects, open_assembly
    from armwarden.policy import apply_overrides, bundled_policy, parse_policy

    sys.setswitchinterval(SWITCH_INTERVAL_S)
    logging.getLogger("armwarden.backends.can").setLevel(logging.ERROR)  # one "holding again" per e-stop cycle
    import yaml

    document = yaml.safe_load(bundled_policy("fr3").read_text())
    # the benchmark calls far faster than an agent would: above the bundled rate limits; no wrench on CAN
    policy = parse_policy(apply_overrides(document, {
        "rate_limits.global_per_minute": 100000, "rate_limits.default_per_minute": 100000,
        "rate_limits.per_tool.plan_to_pose": 100000, "rate_limits.per_tool.execute_plan": 100000,
        "rate_limits.per_tool.plan_to_joints": 100000, "rate_limits.per_tool.reset_estop": 100000,
        "force.require_wrench": False,
    }), source="bench")

    async def approve(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        return types.ElicitResult(action="accept", content={"approve": True, "operator": "bench"})

    def pose(i: int) -> dict[str, Any]:
        return {"position": {"x": 0.40 + 0.02 * (i % 2), "y": 0.05, "z": 0.35}, "preview": False}

    async def one_rate(directory: Path, rate_hz: int) -> dict[str, Any]:
        config = _config_file(directory, rate_hz)
        cell = await open_assembly(*assemble(policy, "can", str(config), str(directory / f"audit-{rate_hz}.jsonl")))
        freeze_long_lived_objects()
        backend: Any = cell.backend  # a CanBackend: its servo loop's timing and config are read
        motors = [*backend.config.joints, *([backend.config.gripper] if backend.config.gripper is not None else [])]
        watch = DampingWatch(backend.config.bus.channel, {m.can_id: m.ranges for m in motors})
        out: dict[str, Any] = {"rate_hz": rate_hz, "seconds": seconds}
        latencies_bus: list[float] = []
        latencies_arrival: list[float] = []
        missed = 0
        calls = {"state": 0, "plan": 0, "execute": 0}
        try:
            async with Client(cell.server.mcp) as load_client, Client(cell.server.mcp, elicitation_callback=approve) as operator:
                loading = True

                async def keep_busy() -> None:
                    i = 0
                    while loading:
                        await load_client.call_tool("get_robot_state", {})
                        calls["state"] += 1
                        await load_client.call_tool("plan_to_pose", pose(i))
                        calls["plan"] += 1
                        if i % 10 == 0:  # a small move now and then (refused while an e-stop is latched)
                            state = (await load_client.call_tool("get_robot_state", {})).structured_content
                            q = state["joint_positions"]
                            goal = [q[0] + (0.05 if i % 20 == 0 else -0.05), *q[1:]]
                            planned = await load_client.call_tool("plan_to_joints", {"joint_positions": goal, "preview": False})
                            if not planned.is_error:
                                await load_client.call_tool("execute_plan", {"plan_id": planned.structured_content["plan_id"]})
                                calls["execute"] += 1
                        i += 1

                async with anyio.create_task_group() as group:
                    group.start_soon(keep_busy)
                    await anyio.sleep(0.5)  # the load is running
                    servo = backend.servo
                    servo.timing.reset()
                    end = time.monotonic() + seconds
                    while time.monotonic() < end:
                        await anyio.sleep(ESTOP_EVERY_S)
                        sent = time.time()
                        watch.arm(sent)
                        await operator.call_tool("estop", {"reason": "bench"})
                        deadline = time.monotonic() + 1.0
                        while watch.found is None and time.monotonic() < deadline:  # noqa: ASYNC110 - set by the listener thread
                            await anyio.sleep(0.002)
                        if watch.found is None:
                            missed += 1
                        else:
                            on_bus, arrived = watch.found
                            latencies_bus.append((on_bus - sent) * 1e3)
                            latencies_arrival.append((arrived - sent) * 1e3)
                        reset = await operator.call_tool("reset_estop", {})
                        assert not reset.is_error, reset.content
                    report = servo.timing.report()
                    loading = False
                    out["ticks"] = report.ticks
                    out["achieved_hz"] = report.rate_hz
                    out["miss_ratio"] = report.miss_ratio
                    out["deadline_misses"] = report.deadline_misses
                    out["max_lateness_ms"] = report.max_lateness_s * 1e3
                    out["jitter_p99_ms"] = report.jitter_p99_s * 1e3
                    out["interval_p50_ms"] = report.interval_p50_s * 1e3
                    out["interval_p99_ms"] = report.interval_p99_s * 1e3
                    out["interval_max_ms"] = report.interval_max_s * 1e3
                    out["estop_to_damping_bus_ms"] = _percentiles(latencies_bus)
                    out["estop_to_damping_arrival_ms"] = _percentiles(latencies_arrival)
                    out["estops_missed"] = missed
                    out["calls"] = dict(calls)
        finally:
            watch.close()
            await close_assembly(cell, "benchmark done")
        return out

    async def run(directory: Path) -> dict[str, Any]:
        return {"rates": [await one_rate(directory, rate) for rate in rates_hz]}

    with tempfile.TemporaryDirectory() as tmp:
        return anyio.run(run, Path(tmp))


def report_can(r: dict[str, Any]) -> None:
    print("## can (7 emulated RobStride actuators on the virtual bus, emulator on its own thread; "
          "server busy with an SDK client in memory)")
    for row in r["rates"]:
        rate, period_ms = row["rate_hz"], 1e3 / row["rate_hz"]
        goal = f"  (goal < 0.5 %: {'met' if row['miss_ratio'] < 0.005 else 'MISSED'})" if rate >= 1000 else ""
        print(f"{rate} Hz for {row['seconds']:g} s: achieved {row['achieved_hz']:.1f} Hz over {row['ticks']} ticks; "
              f"deadline misses {100 * row['miss_ratio']:.2f} % ({row['deadline_misses']}, latest start "
              f"{row['max_lateness_ms']:.2f} ms after schedule){goal}")
        print(f"  period p50 {row['interval_p50_ms']:.3f} ms / p99 {row['interval_p99_ms']:.3f} ms / max "
              f"{row['interval_max_ms']:.2f} ms; p99 jitter |period - {period_ms:g} ms| {row['jitter_p99_ms']:.3f} ms")
        bus, arrival = row["estop_to_damping_bus_ms"], row["estop_to_damping_arrival_ms"]
        if bus["n"]:
            ok = "met" if bus["p99"] <= period_ms else "MISSED"
            print(f"  estop sent -> first damping frame on the bus: {bus['p50']:.2f} ms p50 / {bus['p99']:.2f} ms p99 / "
                  f"{bus['max']:.2f} ms max over {bus['n']} (goal p99 <= {period_ms:g} ms: {ok}); at the listener "
                  f"{arrival['p50']:.2f} / {arrival['p99']:.2f} ms")
        print(f"  e-stops with no damping frame within 1 s: {row['estops_missed']}; load calls: "
              f"{row['calls']['state']} get_robot_state, {row['calls']['plan']} plan_to_pose, {row['calls']['execute']} moves")
