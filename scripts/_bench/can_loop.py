"""`python scripts/bench.py can`: the CAN servo loop while the server handles calls, beside its floor.

One process, as `armwarden serve --backend can --backend-config examples/can_sim.yaml` assembles
it (the daemon's switch interval and garbage-collector settings), with the 7 emulated RobStride
actuators and the gripper actuator on python-can's in-process virtual bus (the emulator on its
own thread; kernel vcan is not available here). For each control rate (500 Hz, 1 kHz):

- **ours, busy** (the issue's figure, `seconds` long): one SDK client in memory keeps the server
  busy (`get_robot_state` + `plan_to_pose` in a loop, a small executed move every few loops) and
  an operator client calls `estop` then an approved `reset_estop` every second. Measured: the
  servo loop's achieved tick rate, deadline-miss rate (a tick that began more than one period
  after it was scheduled; goal < 0.5 % at 1 kHz) and p99 period jitter, from the loop's own
  `ServoLoop.timing`; and `estop` sent → the first damping frame (kp = 0, kd > 0) on the bus, as
  stamped by the virtual bus when it was sent (goal ≤ one control period), p50/p99.
- **ours, busy, FIFO**: the same, with `realtime_priority: 50` (the servo thread under SCHED_FIFO).
- **ours, idle**: the same daemon with no calls (`compare_seconds` long).
- **floor, idle / busy**: what CPython and python-can allow with none of our code in the loop: a
  bare thread that keeps the same schedule (`TickTiming`, the same sleep/wake logic) and sends 8
  pre-encoded command frames a tick, an echo thread that answers each with a pre-encoded feedback
  frame, and a python-can Notifier with a listener that does nothing; "busy" adds the same SDK
  load on a fake-backend daemon in the same process. Our share is the difference between the rows.
"""

from __future__ import annotations

import logging
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench_common import approve_all, bench_policy, percentiles  # scripts/_bench is on sys.path (scripts/bench.py puts it there)

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "can_sim.yaml"
RATES_HZ = (500, 1000)
#: time between two e-stops [s] (each followed by a reset)
ESTOP_EVERY_S = 1.0
#: frames a floor tick sends (7 joints and the gripper, as the arm does)
FLOOR_FRAMES = 8
#: SCHED_FIFO priority of the servo thread in the "FIFO" rows (`realtime_priority` in the config; None: no such rows)
REALTIME_PRIORITY = 50
#: the stop channel's bearer token in the benchmark
BENCH_TOKEN = "bench-token"


def _percentiles(values: list[float]) -> dict[str, float]:
    return percentiles(values, (50, 99))


class DampingWatch:
    """Finds the first damping command frame (kp = 0, kd > 0) on the virtual channel after
    `arm()`, with the bus's send stamp (`time.time`) and its own arrival stamp.

    It joins the channel only for each e-stop's window (`arm` .. found or `disarm`): a listener
    that stayed on the channel would make python-can's virtual bus copy every frame once more,
    and wake one more thread per frame — load the measured loop does not have on hardware."""

    def __init__(self, channel: str, ranges: dict[int, Any]) -> None:
        self._channel = channel
        self._ranges = ranges
        self.found: tuple[float, float] | None = None  # (sent on the bus, arrived here), time.time
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def arm(self, after: float) -> None:
        """Start listening (before the e-stop is requested) for a damping frame sent at or after `after`."""
        import can

        self.disarm()
        self.found = None
        self._stop.clear()
        bus = can.Bus(interface="virtual", channel=self._channel)  # on the channel from now on
        self._thread = threading.Thread(target=self._listen, args=(bus, after), name="bench-damping-watch", daemon=True)
        self._thread.start()

    def disarm(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=2.0)
            self._thread = None

    def _listen(self, bus: Any, after: float) -> None:
        from armwarden.backends.can import robstride as rs
        from armwarden.backends.can import robstride_device as rs_device

        try:
            while not self._stop.is_set():
                msg = bus.recv(timeout=0.05)
                arrived = time.time()
                if msg is None or msg.is_error_frame or not msg.is_extended_id or msg.timestamp < after:
                    continue
                if rs.split_id(msg.arbitration_id).comm_type != rs.CommType.CONTROL:
                    continue
                motor = msg.arbitration_id & 0xFF
                if motor not in self._ranges:
                    continue  # not an actuator of this arm
                command = rs_device.unpack_control(msg.arbitration_id, bytes(msg.data), self._ranges[motor])[1]
                if command.kp == 0.0 and command.kd > 0.0:
                    self.found = (msg.timestamp, arrived)
                    return
        finally:
            bus.shutdown()

    def close(self) -> None:
        self.disarm()


def _config_file(directory: Path, rate_hz: int, realtime_priority: int | None) -> Path:
    import yaml

    document = yaml.safe_load(EXAMPLE.read_text())
    document["bus"]["channel"] = f"armwarden-bench-{uuid.uuid4().hex}"
    document["control_rate_hz"] = rate_hz
    document["realtime_priority"] = realtime_priority
    path = directory / f"can-{rate_hz}-{uuid.uuid4().hex[:8]}.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


async def _keep_busy(client: Any, running: Callable[[], bool], calls: dict[str, int]) -> None:
    """The server's load: state and planning in a loop, a small executed move every ten loops
    (refused while an e-stop is latched)."""
    i = 0
    while running():
        await client.call_tool("get_robot_state", {})
        calls["state"] += 1
        pose = {"position": {"x": 0.40 + 0.02 * (i % 2), "y": 0.05, "z": 0.35}, "preview": False}
        await client.call_tool("plan_to_pose", pose)
        calls["plan"] += 1
        if i % 10 == 0:
            state = (await client.call_tool("get_robot_state", {})).structured_content
            q = state["joint_positions"]
            goal = [q[0] + (0.05 if i % 20 == 0 else -0.05), *q[1:]]
            planned = await client.call_tool("plan_to_joints", {"joint_positions": goal, "preview": False})
            if not planned.is_error:
                await client.call_tool("execute_plan", {"plan_id": planned.structured_content["plan_id"]})
                calls["execute"] += 1
        i += 1


def _timing(report: Any) -> dict[str, Any]:
    return {
        "ticks": report.ticks, "achieved_hz": report.rate_hz, "miss_ratio": report.miss_ratio,
        "deadline_misses": report.deadline_misses, "max_lateness_ms": report.max_lateness_s * 1e3,
        "jitter_p99_ms": report.jitter_p99_s * 1e3, "interval_p50_ms": report.interval_p50_s * 1e3,
        "interval_p99_ms": report.interval_p99_s * 1e3, "interval_max_ms": report.interval_max_s * 1e3,
    }


class BareLoop:
    """The floor: a thread on the servo loop's schedule sending pre-encoded frames, an echo
    thread answering each, and a Notifier with a listener that does nothing."""

    def __init__(self, rate_hz: int) -> None:
        import can

        from armwarden.backends.can import robstride as rs
        from armwarden.backends.can import robstride_device as rs_device
        from armwarden.backends.can import robstride_frames as rs_frames
        from armwarden.backends.can.command import MotorCommand
        from armwarden.backends.can.ranges import model_ranges
        from armwarden.backends.ticktiming import TickTiming

        channel = f"armwarden-floor-{uuid.uuid4().hex}"
        ranges = model_ranges("RS03")
        command = MotorCommand(0.1, 0.0, 100.0, 2.0, 0.0)
        feedback = rs.Feedback(1, rs.MotorMode.RUN, rs.FeedbackFault(0), 0.1, 0.0, 0.0, 30.0)
        frames = [rs_frames.control_frame(motor, command, ranges) for motor in range(1, FLOOR_FRAMES + 1)]
        self._commands = [can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=True) for f in frames]
        reply = rs_device.feedback_frame(feedback, ranges, host_id=0xFD)
        self._reply = can.Message(arbitration_id=reply.arbitration_id, data=reply.data, is_extended_id=True)
        self.period_s = 1.0 / rate_hz
        self.timing = TickTiming(self.period_s)
        self.replies = 0
        self._host = can.Bus(interface="virtual", channel=channel)
        self._device = can.Bus(interface="virtual", channel=channel)
        self._notifier = can.Notifier(self._host, [self._on_reply], timeout=0.05)
        self._running = True
        self._wake = threading.Event()
        self._threads = [threading.Thread(target=self._loop, name="floor-loop", daemon=True),
                         threading.Thread(target=self._echo, name="floor-echo", daemon=True)]
        for thread in self._threads:
            thread.start()

    def _on_reply(self, msg: Any) -> None:
        self.replies += 1

    def _loop(self) -> None:  # the scheduling of ServoLoop._run, with nothing but the sends in the tick
        period = self.period_s
        next_tick = time.perf_counter()
        while self._running:
            self.timing.record(time.perf_counter(), next_tick)
            for message in self._commands:
                self._host.send(message, timeout=0.002)
            next_tick += period
            delay = next_tick - time.perf_counter()
            if delay < -10 * period:
                next_tick = time.perf_counter()
            elif delay > 0 and self._wake.wait(delay):
                self._wake.clear()

    def _echo(self) -> None:
        while self._running:
            if self._device.recv(timeout=0.05) is not None:
                self._device.send(self._reply)

    def close(self) -> None:
        self._running = False
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._notifier.stop()
        self._host.shutdown()
        self._device.shutdown()


class ChannelSender:
    """A separate process that POSTs an e-stop to the stop channel when asked and answers with
    the `time.time()` at which it began (an operator's stop button is not in the daemon's process;
    in the same process it would wait for the interpreter lock like everything else)."""

    _CODE = (
        "import sys, time\n"
        "from armwarden.stopchannel.client import send_estop\n"
        "url, token = sys.argv[1], sys.argv[2]\n"
        "for _ in sys.stdin:\n"
        "    began = time.time()\n"
        "    send_estop(url, token, 'bench')\n"
        "    print(repr(began), flush=True)\n"
    )

    def __init__(self, url: str, token: str) -> None:
        import os
        import subprocess

        source = str(Path(__file__).resolve().parents[2] / "src")
        env = {**os.environ, "PYTHONPATH": source + os.pathsep + os.environ.get("PYTHONPATH", "")}
        self._process = subprocess.Popen([sys.executable, "-c", self._CODE, url, token], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True, env=env)

    def send(self) -> float:
        """One e-stop; when the other process began sending it (time.time)."""
        assert self._process.stdin is not None and self._process.stdout is not None
        self._process.stdin.write("go\n")
        self._process.stdin.flush()
        return float(self._process.stdout.readline())

    def close(self) -> None:
        if self._process.stdin is not None:
            self._process.stdin.close()
        self._process.wait(timeout=5)


def bench_can(seconds: float = 60.0, rates_hz: tuple[int, ...] = RATES_HZ, compare_seconds: float | None = None,
              realtime_priority: int | None = REALTIME_PRIORITY) -> dict[str, Any]:
    import asyncio

    import anyio
    import anyio.to_thread
    from mcp import Client

    from armwarden.core.errors import ArmWardenError
    from armwarden.daemon.shutdown import close_assembly
    from armwarden.daemon.startup import SWITCH_INTERVAL_S, assemble, freeze_long_lived_objects, open_assembly
    from armwarden.stopchannel.external import ExternalStops
    from armwarden.stopchannel.server import StopChannel

    sys.setswitchinterval(SWITCH_INTERVAL_S)
    logging.getLogger("armwarden.backends.can").setLevel(logging.ERROR)  # one "holding again" per e-stop cycle
    policy = bench_policy(**{"force.require_wrench": False})  # no wrench on CAN
    compare = min(seconds, 20.0) if compare_seconds is None else compare_seconds

    async def loaded(cell: Any, run: Callable[[], Any]) -> dict[str, int]:
        """Run `run()` (awaitable) while an SDK client keeps `cell`'s server busy; the calls made."""
        calls = {"state": 0, "plan": 0, "execute": 0}
        busy = True
        async with Client(cell.server.mcp) as load_client, anyio.create_task_group() as group:
            group.start_soon(_keep_busy, load_client, lambda: busy, calls)
            await anyio.sleep(0.5)  # the load is running
            await run()
            busy = False
        return calls

    async def floor(directory: Path, rate_hz: int, busy: bool) -> dict[str, Any]:
        cell = await open_assembly(assemble(policy, "fake", None, str(directory / f"audit-floor-{uuid.uuid4().hex[:8]}.jsonl"))) \
            if busy else None
        freeze_long_lived_objects()
        loop = BareLoop(rate_hz)
        out: dict[str, Any] = {"rate_hz": rate_hz, "seconds": compare, "what": f"floor, {'busy' if busy else 'idle'}"}
        try:
            async def measure() -> None:
                loop.timing.reset()
                await anyio.sleep(compare)
                out.update(_timing(loop.timing.report()))

            if cell is None:
                await anyio.sleep(0.5)
                await measure()
            else:
                out["calls"] = await loaded(cell, measure)
        finally:
            loop.close()
            if cell is not None:
                await close_assembly(cell, "benchmark done")
        return out

    async def ours(directory: Path, rate_hz: int, busy: bool, realtime_priority: int | None = None) -> dict[str, Any]:
        config = _config_file(directory, rate_hz, realtime_priority)
        cell = await open_assembly(assemble(policy, "can", str(config), str(directory / f"audit-{uuid.uuid4().hex[:8]}.jsonl")))
        freeze_long_lived_objects()
        backend: Any = cell.backend  # a CanBackend: its servo loop's timing and config are read
        servo = backend.servo
        length = seconds if busy else compare
        what = f"ours, {'busy' if busy else 'idle'}" + ("" if realtime_priority is None else ", FIFO")
        out: dict[str, Any] = {"rate_hz": rate_hz, "seconds": length, "what": what}
        try:
            if not busy:
                await anyio.sleep(0.5)
                servo.timing.reset()
                await anyio.sleep(length)
                out.update(_timing(servo.timing.report()))
                return out
            motors = [*backend.config.joints, *([backend.config.gripper] if backend.config.gripper is not None else [])]
            watch = DampingWatch(backend.config.bus.channel, {m.can_id: m.ranges for m in motors})
            # the stop channel as `serve --estop-port` runs it (its own thread and socket, 127.0.0.1)
            external = ExternalStops(cell.guard.stopper, cell.audit, asyncio.get_running_loop())
            channel = StopChannel(authenticate=lambda token: "bench" if token == BENCH_TOKEN else None,
                                  latch_and_stop=external.latch_and_stop_for("stop_channel"), on_event=external.record,
                                  on_refused=external.record_refusal).start()
            sender = ChannelSender(channel.url, BENCH_TOKEN)
            entered: list[float] = []  # when the backend's e-stop began (time.time): our share starts there
            original = backend._emergency_stop_now

            def stamped() -> None:
                entered.append(time.time())
                original()

            backend._emergency_stop_now = stamped
            paths: dict[str, dict[str, list[float]]] = {p: {"bus": [], "ours": []} for p in ("tool", "channel")}
            missed = 0
            async with Client(cell.server.mcp, elicitation_callback=approve_all) as operator:
                async def measure() -> None:
                    nonlocal missed
                    servo.timing.reset()
                    end = time.monotonic() + length
                    k = 0
                    while time.monotonic() < end:
                        await anyio.sleep(ESTOP_EVERY_S)
                        path = "tool" if k % 2 == 0 else "channel"
                        k += 1
                        entered.clear()
                        sent = time.time()
                        watch.arm(sent)
                        if path == "tool":
                            await operator.call_tool("estop", {"reason": "bench"})
                        else:  # from another process, as an operator's stop button would
                            sent = await anyio.to_thread.run_sync(sender.send)
                        deadline = time.monotonic() + 1.0
                        while watch.found is None and time.monotonic() < deadline:  # noqa: ASYNC110 - set by the listener thread
                            await anyio.sleep(0.002)
                        watch.disarm()
                        if watch.found is None:
                            missed += 1
                        else:
                            on_bus = watch.found[0]
                            paths[path]["bus"].append((on_bus - sent) * 1e3)
                            if entered:
                                paths[path]["ours"].append((on_bus - entered[0]) * 1e3)
                        reset = await operator.call_tool("reset_estop", {})
                        assert not reset.is_error, reset.content
                    out.update(_timing(servo.timing.report()))

                try:
                    out["calls"] = await loaded(cell, measure)
                finally:
                    watch.close()
                    sender.close()
                    channel.close()
                    backend._emergency_stop_now = original
            out["estop_ms"] = {path: {k: _percentiles(v) for k, v in figures.items()} for path, figures in paths.items()}
            out["estops_missed"] = missed
            return out
        finally:
            await close_assembly(cell, "benchmark done")

    async def run(directory: Path) -> dict[str, Any]:
        rows = []
        for rate in rates_hz:
            rows.append(await floor(directory, rate, busy=False))
            rows.append(await floor(directory, rate, busy=True))
            rows.append(await ours(directory, rate, busy=False))
            rows.append(await ours(directory, rate, busy=True))
            if realtime_priority is not None:
                try:
                    rows.append(await ours(directory, rate, busy=True, realtime_priority=realtime_priority))
                except ArmWardenError as exc:  # no CAP_SYS_NICE here: say so instead of a row
                    print(f"can: the FIFO row at {rate} Hz was refused: {exc}", file=sys.stderr)
        return {"rows": rows}

    with tempfile.TemporaryDirectory() as tmp:
        return anyio.run(run, Path(tmp))


def report_can(r: dict[str, Any]) -> None:
    print("## can (7 emulated RobStride actuators + gripper on the virtual bus, emulator on its own thread; "
          "'busy': an SDK client in memory keeps the server busy)")
    print(f"| {'rate':>6} | {'run':<18} | {'s':>4} | {'achieved':>9} | {'misses':>8} | {'p99 jitter':>10} | {'latest start':>12} |")
    for row in r["rows"]:
        rate, period_ms = row["rate_hz"], 1e3 / row["rate_hz"]
        print(f"| {rate:>4}Hz | {row['what']:<18} | {row['seconds']:>4g} | {row['achieved_hz']:>6.1f} Hz | "
              f"{100 * row['miss_ratio']:>6.2f} % | {row['jitter_p99_ms']:>7.3f} ms | {row['max_lateness_ms']:>9.2f} ms |")
    for row in r["rows"]:
        if "estop_ms" not in row:
            continue
        rate, period_ms = row["rate_hz"], 1e3 / row["rate_hz"]
        goal = f" (goal < 0.5 %: {'met' if row['miss_ratio'] < 0.005 else 'MISSED'})" if rate >= 1000 else ""
        print(f"{rate} Hz, {row['what']}: deadline misses {100 * row['miss_ratio']:.2f} %{goal}; period p50 "
              f"{row['interval_p50_ms']:.3f} / p99 {row['interval_p99_ms']:.3f} / max {row['interval_max_ms']:.2f} ms")
        paths = (("tool", "`estop` tool (SDK client in memory)"), ("channel", "stop channel (POST /estop from another process)"))
        for path, label in paths:
            figures = row["estop_ms"][path]
            bus, ours = figures["bus"], figures["ours"]
            if bus["n"]:
                ok = "met" if bus["p99"] <= period_ms else "MISSED"
                print(f"  {label} sent -> first damping frame on the bus: {bus['p50']:.2f} ms p50 / {bus['p99']:.2f} ms p99 / "
                      f"{bus['max']:.2f} ms max over {bus['n']} (goal p99 <= {period_ms:g} ms: {ok}); of which the backend's "
                      f"e-stop -> frame: {ours['p50']:.2f} / {ours['p99']:.2f} ms")
        calls = row["calls"]
        print(f"  e-stops with no damping frame within 1 s: {row['estops_missed']}; load calls: "
              f"{calls['state']} get_robot_state, {calls['plan']} plan_to_pose, {calls['execute']} moves")
