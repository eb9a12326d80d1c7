"""`python scripts/bench.py mujoco`: the MuJoCo backend while the server handles calls.

One process, as `armwarden serve` assembles it (the daemon's switch interval and garbage-collector
settings), driven by the official SDK client in memory. While one client keeps the server busy
with `get_robot_state` and `plan_to_pose` calls, the run measures

- the real-time factor of the 1 kHz physics (simulated / wall time, and steps dropped);
- e-stop latency: the `estop` call sent mid-motion → the hold commanded (wall), → every joint
  slower than 1e-3 rad/s (wall and simulated), beside the physical floor of this arm model: the
  time its joint torque limits need to brake the measured speed, joint by joint, ignoring
  gravity and coupling (no stop can be faster);
- render time of a 640×480 `camera_snapshot` (the backend's render, and the tool round trip);
- `get_robot_state` and `plan_to_pose` round trips on mujoco and on the fake, interleaved in
  blocks in the same run (goal: mujoco within 1.5× the fake).
"""

# mujoco ships compiled modules without type stubs (see src/armwarden/backends/mujoco/model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from bench_common import approve_all, bench_policy, percentiles, timed_ms  # scripts/_bench is on sys.path (scripts/bench.py puts it there)

#: joint speed below which the arm counts as still [rad/s] (the issue's bar)
STILL_RAD_S = 1e-3
BLOCK = 20


class StillWatch:
    """A thread that reads the backend's published samples every 0.2 ms and notes the first one
    after `arm()` in which every joint is slower than `STILL_RAD_S`."""

    def __init__(self, backend: Any) -> None:
        self.backend = backend
        self.armed_after: float | None = None
        self.found: tuple[float, float] | None = None  # (monotonic stamp, simulated time)
        self._done = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def arm(self, after: float) -> None:
        self.found, self.armed_after = None, after

    def _run(self) -> None:
        while not self._done:
            sample = self.backend.arm.measured
            after = self.armed_after
            if (after is not None and self.found is None and sample.stamp >= after
                    and float(np.max(np.abs(sample.velocities))) < STILL_RAD_S):
                self.found = (sample.stamp, sample.sim_s)
            time.sleep(0.0002)

    def close(self) -> None:
        self._done = True
        self._thread.join(1.0)


def braking_floor_s(backend: Any) -> float:
    """Shortest time the arm's torque limits can bring the measured joint speeds to zero [s]."""
    import mujoco

    model, cell = backend.arm.model, backend.sim
    sample = backend.arm.measured
    probe = mujoco.MjData(model)
    probe.qpos[:] = sample.scene_qpos
    mujoco.mj_forward(model, probe)
    inertia = np.empty(len(cell.arm_dofs))
    for index, dof in enumerate(cell.arm_dofs):
        unit, column = np.zeros(model.nv), np.zeros(model.nv)
        unit[dof] = 1.0
        mujoco.mj_mulM(model, probe, column, unit)
        inertia[index] = column[dof]
    joints = [model.joint(name).id for name in cell.arm_joints]
    torque = np.asarray(model.jnt_actfrcrange[joints][:, 1])  # the URDF effort limits
    return float(np.max(np.abs(sample.velocities) * inertia / torque))


def bench_mujoco(cycles: int = 20, repeats: int = 200) -> dict[str, Any]:
    import anyio
    from mcp import Client

    from armwarden.daemon.shutdown import close_assembly
    from armwarden.daemon.startup import SWITCH_INTERVAL_S, assemble, freeze_long_lived_objects, open_assembly

    sys.setswitchinterval(SWITCH_INTERVAL_S)
    policy = bench_policy()

    def pose(i: int) -> dict[str, Any]:
        return {"position": {"x": 0.40 + 0.02 * (i % 2), "y": 0.05, "z": 0.35}, "preview": False}

    async def run(directory: Path) -> dict[str, Any]:
        out: dict[str, Any] = {}
        fake = await open_assembly(assemble(policy, "fake", None, str(directory / "fake-audit.jsonl")))
        cell = await open_assembly(assemble(policy, "mujoco", None, str(directory / "mujoco-audit.jsonl")))
        freeze_long_lived_objects()
        backend: Any = cell.backend  # a MujocoBackend: its published sample and step counters are read
        watch = StillWatch(backend)
        try:
            async with Client(fake.server.mcp) as on_fake, Client(cell.server.mcp, elicitation_callback=approve_all) as on_cell, \
                    Client(cell.server.mcp) as load_client:
                # ---- calls on both backends, interleaved in blocks
                series: dict[str, list[float]] = {"state_fake": [], "state_mujoco": [], "plan_fake": [], "plan_mujoco": []}
                sim_start, wall_start, steps_start = backend.arm.measured.sim_s, time.perf_counter(), backend.arm.step_count
                dropped_start = backend.arm.dropped_steps
                for block in range(max(1, repeats // BLOCK)):
                    for _ in range(BLOCK):
                        series["state_fake"].append(await timed_ms(on_fake, "get_robot_state", {}))
                        series["state_mujoco"].append(await timed_ms(on_cell, "get_robot_state", {}))
                    for i in range(BLOCK // 4):
                        series["plan_fake"].append(await timed_ms(on_fake, "plan_to_pose", pose(block + i)))
                        series["plan_mujoco"].append(await timed_ms(on_cell, "plan_to_pose", pose(block + i)))
                wall = time.perf_counter() - wall_start
                out["calls"] = {name: percentiles(values) for name, values in series.items()}
                out["rtf_while_serving"] = (backend.arm.measured.sim_s - sim_start) / wall
                out["steps_per_s"] = (backend.arm.step_count - steps_start) / wall
                out["dropped_steps"] = backend.arm.dropped_steps - dropped_start

                # ---- renders
                renders: list[float] = []
                for _ in range(10):
                    start = time.perf_counter()
                    await backend.camera_snapshot("scene")
                    renders.append((time.perf_counter() - start) * 1e3)
                out["render_backend_ms"] = percentiles(renders)
                out["render_tool_ms"] = percentiles([await timed_ms(on_cell, "camera_snapshot", {"camera": "scene"})
                                                     for _ in range(10)])

                # ---- e-stops mid-motion while a client keeps the server busy
                stops: list[dict[str, float]] = []
                missed = 0
                loading = True

                async def keep_busy() -> None:
                    i = 0
                    while loading:
                        await load_client.call_tool("get_robot_state", {})
                        await load_client.call_tool("plan_to_pose", pose(i))
                        i += 1

                async with anyio.create_task_group() as group:
                    group.start_soon(keep_busy)
                    sim_start, wall_start, dropped_start = backend.arm.measured.sim_s, time.perf_counter(), backend.arm.dropped_steps
                    for cycle in range(cycles):
                        state = (await on_cell.call_tool("get_robot_state", {})).structured_content
                        q = state["joint_positions"]
                        goal = [q[0] + (0.4 if cycle % 2 == 0 else -0.4), *q[1:]]
                        planned = await on_cell.call_tool("plan_to_joints", {"joint_positions": goal, "velocity_scaling": 0.3,
                                                                             "preview": False})
                        assert not planned.is_error, planned.content
                        plan = planned.structured_content
                        moving: dict[str, Any] = {}

                        async def execute(plan_id: str = plan["plan_id"], holder: dict[str, Any] = moving) -> None:
                            holder["result"] = await on_cell.call_tool("execute_plan", {"plan_id": plan_id})

                        speed_at_stop = floor_s = sent_mono = sent_sim = call_done = 0.0
                        async with anyio.create_task_group() as motion:
                            motion.start_soon(execute)
                            while cell.guard.motion_status().progress < 0.4:  # noqa: ASYNC110 - polled: moved by the physics thread
                                await anyio.sleep(0.002)
                            speed_at_stop = float(np.max(np.abs(backend.arm.measured.velocities)))
                            floor_s = braking_floor_s(backend)
                            sent_mono, sent_sim = time.monotonic(), backend.arm.measured.sim_s
                            watch.arm(sent_mono)
                            await on_cell.call_tool("estop", {"reason": "bench"})
                            call_done = time.monotonic()
                        deadline = time.monotonic() + 3.0
                        while watch.found is None and time.monotonic() < deadline:  # noqa: ASYNC110 - set by the watch thread
                            await anyio.sleep(0.005)
                        hold = backend.last_stop_stamp
                        if watch.found is None or hold is None:
                            missed += 1
                        else:
                            still_mono, still_sim = watch.found
                            stops.append({"hold_ms": (hold - sent_mono) * 1e3, "call_ms": (call_done - sent_mono) * 1e3,
                                          "still_wall_ms": (still_mono - sent_mono) * 1e3,
                                          "still_sim_ms": (still_sim - sent_sim) * 1e3,
                                          "floor_ms": floor_s * 1e3, "speed_rad_s": speed_at_stop})
                        reset = await on_cell.call_tool("reset_estop", {})
                        assert not reset.is_error, reset.content
                    wall = time.perf_counter() - wall_start
                    out["rtf_during_estops"] = (backend.arm.measured.sim_s - sim_start) / wall
                    out["dropped_steps_during_estops"] = backend.arm.dropped_steps - dropped_start
                    loading = False
                out["estops"] = {key: percentiles([s[key] for s in stops]) for key in stops[0]} if stops else {}
                out["estops_missed"] = missed
                out["estop_cycles"] = cycles
        finally:
            watch.close()
            await close_assembly(cell, "benchmark done")
            await close_assembly(fake, "benchmark done")
        return out

    with tempfile.TemporaryDirectory() as tmp:
        return anyio.run(run, Path(tmp))


def report_mujoco(r: dict[str, Any]) -> None:
    calls = r["calls"]
    print("## mujoco (1 kHz physics, real time, in one process with the server; SDK client in memory)")
    rtf = r["rtf_while_serving"]
    print(f"real-time factor while serving calls: {rtf:.3f} ({r['steps_per_s']:.0f} steps/s, {r['dropped_steps']} dropped)"
          f"  (goal >= 1.0: {'met' if rtf >= 0.99 and r['dropped_steps'] == 0 else 'MISSED'})")
    print(f"real-time factor during the e-stop cycles (a client loading the server): {r['rtf_during_estops']:.3f} "
          f"({r['dropped_steps_during_estops']} steps dropped)")
    for what, fake_key, cell_key in (("get_robot_state", "state_fake", "state_mujoco"), ("plan_to_pose", "plan_fake", "plan_mujoco")):
        fake, cell = calls[fake_key], calls[cell_key]
        ratio = cell["p50"] / fake["p50"]
        print(f"{what}: mujoco {cell['p50']:.2f} ms p50 / {cell['p95']:.2f} ms p95, fake {fake['p50']:.2f} / {fake['p95']:.2f} ms "
              f"over {cell['n']}: ratio of medians {ratio:.2f} (goal <= 1.5: {'met' if ratio <= 1.5 else 'MISSED'})")
    render, tool = r["render_backend_ms"], r["render_tool_ms"]
    print(f"640x480 snapshot: render + PNG {render['p50']:.1f} ms p50 / {render['p95']:.1f} ms p95; "
          f"camera_snapshot round trip {tool['p50']:.1f} / {tool['p95']:.1f} ms")
    stops = r["estops"]
    print(f"e-stops mid-motion: {r['estop_cycles']} cycles, {r['estops_missed']} missed (arm not still within 3 s)")
    if stops:
        def row(label: str, key: str) -> str:
            s = stops[key]
            return f"{label} {s['p50']:.1f} ms p50 / {s['p95']:.1f} ms p95 / {s['max']:.1f} ms max"

        print("  " + row("estop sent -> hold commanded (wall):", "hold_ms"))
        print("  " + row("estop sent -> call answered (wall):", "call_ms"))
        still = stops["still_wall_ms"]
        print("  " + row("estop sent -> every joint below 1e-3 rad/s (wall):", "still_wall_ms")
              + f"  (goal <= 5 ms p95: {'met' if still['p95'] <= 5 else 'MISSED'})")
        print("  " + row("the same in simulated time:", "still_sim_ms"))
        print("  " + row("physical floor, torque-limited braking of the speed at the stop:", "floor_ms"))
        print(f"  joint speed at the stop: {stops['speed_rad_s']['p50']:.2f} rad/s p50")
