"""`scripts/bench.py fk`: the compiled forward kinematics beside numpy and Pinocchio, in one run.

What is timed, on the bundled FR3 (`BatchFK.for_robot`: the 8 moving links that carry collision
geometry and the TCP, plus every joint — 18 poses per configuration):

- single configuration: `BatchFK.poses(q, out)` from Python (validation + kernel, into a reused
  output; allocating a new one is timed too), the
  bare compiled kernel `fk_into` with a preallocated output (what a compiled checker pays per
  call from Python; from inside another numba kernel there is no dispatch at all), and Pinocchio:
  `forwardKinematics` + `updateFramePlacements`, with and without reading the 9 frame poses into
  numpy (a checker must read them);
- a batch of 64 configurations (samples along a 0.5 rad segment): `BatchFK.poses_batch` (reused
  output, and allocating), the same
  chain evaluated by plain numpy vectorised over the batch (one Python step per joint and
  frame), Pinocchio per configuration with the reads, and `RobotModel.joint_frames` (today's
  envelope path);
- compilation: a cold import (empty cache directory: numba compiles) and a warm one (the
  machine code loaded from that directory), each in a fresh process, beside importing numba.

Everything timed is interleaved round by round so that the shared machine's noise hits all alike;
in each round each series runs once untimed, then `calls` timed calls one by one (the series
before it evicts its code and data from the caches: the first call after the Pinocchio loop costs
about 5 µs more, which is the neighbours' cost, not FK's). Per-call median and p95 over all calls.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

SRC = Path(__file__).resolve().parents[2] / "src"
BATCH = 64
#: targets derived from issue 25's budgets (state check ≤ 10 µs, motion check ≤ 100 µs median):
#: FK may take a fifth of the first and a third of the second
TARGET_SINGLE_US = 2.0
TARGET_BATCH_US = 32.0
TARGET_RATIO_TO_PINOCCHIO = 10.0


def numpy_poses_batch(chain: Any, qs: np.ndarray) -> np.ndarray:
    """The chain evaluated with plain numpy, vectorised over the batch: the alternative to numba."""
    from armwarden.robot.batch_fk import JointKind

    n = len(qs)
    n_joints = len(chain.joint_names)
    out = np.empty((n, n_joints + len(chain.frame_names), 4, 4))
    out[:, 0] = chain.placements[0]
    eye = np.eye(3)
    for j in range(1, n_joints):
        parent = out[:, chain.parents[j]] @ chain.placements[j]
        value = qs[:, chain.q_index[j]]
        motion = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        axis = chain.axes[j]
        if chain.kinds[j] == JointKind.PRISMATIC:
            motion[:, :3, 3] = value[:, None] * axis
        else:
            skew = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
            c, s = np.cos(value)[:, None, None], np.sin(value)[:, None, None]
            motion[:, :3, :3] = eye + s * skew + (1.0 - c) * (skew @ skew)
        out[:, j] = parent @ motion
    out[:, n_joints:] = out[:, chain.frame_joints] @ chain.frame_placements
    return out


def _once_us(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return (time.perf_counter() - start) * 1e6


def _import_seconds(code: str, cache_dir: Path) -> float:
    """Wall time of `code` in a fresh interpreter with numba's cache in `cache_dir`, measured inside it."""
    env = {"PYTHONPATH": str(SRC), "NUMBA_CACHE_DIR": str(cache_dir), "PATH": "/usr/bin:/bin"}
    timed = f"import time; _t = time.perf_counter(); {code}; print(time.perf_counter() - _t)"
    result = subprocess.run([sys.executable, "-c", timed], env=env, capture_output=True, text=True, check=True, timeout=600)
    return float(result.stdout.split()[-1])


def bench_fk(rounds: int = 400, calls: int = 5) -> dict[str, Any]:
    import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

    from armwarden.policy import bundled_policy, load_policy
    from armwarden.robot import build_robot
    from armwarden.robot.batch_fk import BatchFK, fk_into

    robot = build_robot(load_policy(bundled_policy("fr3")))
    fk = BatchFK.for_robot(robot)
    model, data = robot.model, robot.data
    frame_ids = [model.getFrameId(name) for name in fk.frame_names]
    ready = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
    delta = np.array([0.5, 0.25, -0.2, 0.3, 0.2, -0.3, 0.4])
    segment = ready + np.linspace(0.0, 1.0, BATCH)[:, None] * delta
    q = segment[BATCH // 3].copy()
    out_single = np.empty((fk.n_nodes, 4, 4))
    out_batch = np.empty((BATCH, fk.n_nodes, 4, 4))

    # the alternatives agree before they are timed
    reference = fk.poses_batch(segment)
    numpy_error = float(np.abs(numpy_poses_batch(fk.chain, segment) - reference).max())

    def pinocchio_no_read() -> None:
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)

    def pinocchio_read(config: np.ndarray) -> list[np.ndarray]:
        pin.forwardKinematics(model, data, config)
        pin.updateFramePlacements(model, data)
        return [data.oMf[f].homogeneous for f in frame_ids]

    def pinocchio_batch() -> None:
        for config in segment:
            pinocchio_read(config)

    series: dict[str, Callable[[], object]] = {
        "single_batchfk": lambda: fk.poses(q, out_single),
        "single_batchfk_allocating": lambda: fk.poses(q),
        "single_kernel": lambda: fk_into(q, fk.node_ints, fk.node_floats, out_single),
        "single_pinocchio_no_read": pinocchio_no_read,
        "single_pinocchio_read": lambda: pinocchio_read(q),
        "batch_batchfk": lambda: fk.poses_batch(segment, out_batch),
        "batch_batchfk_allocating": lambda: fk.poses_batch(segment),
        "batch_numpy": lambda: numpy_poses_batch(fk.chain, segment),
        "batch_pinocchio_read": pinocchio_batch,
        "batch_robotmodel_joint_frames": lambda: robot.joint_frames(segment),
    }
    times: dict[str, list[float]] = {name: [] for name in series}
    for _ in range(rounds):
        for name, fn in series.items():
            fn()  # untimed: the series before it evicted this one's code and data from the caches
            times[name] += [_once_us(fn) for _ in range(calls)]
    result: dict[str, Any] = {"batch": BATCH, "poses_per_configuration": fk.n_nodes, "frames": list(fk.frame_names),
                              "numpy_max_difference": numpy_error}
    for name, values in times.items():
        result[f"{name}_us_median"] = statistics.median(values)
        result[f"{name}_us_p95"] = float(np.percentile(values, 95))
    result["ratio_batch_pinocchio_to_batchfk"] = result["batch_pinocchio_read_us_median"] / result["batch_batchfk_us_median"]
    result["ratio_batch_numpy_to_batchfk"] = result["batch_numpy_us_median"] / result["batch_batchfk_us_median"]
    result["ratio_single_pinocchio_to_batchfk"] = result["single_pinocchio_read_us_median"] / result["single_batchfk_us_median"]

    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "numba-cache"
        result["import_numba_s"] = _import_seconds("import numba", cache)
        result["import_cold_s"] = _import_seconds("import armwarden.robot.batch_fk", cache)
        result["import_warm_s"] = _import_seconds("import armwarden.robot.batch_fk", cache)
    return result


def _met(value: float, target: float, *, at_least: bool = False) -> str:
    ok = value >= target if at_least else value <= target
    return "met" if ok else "MISSED"


def report_fk(r: dict[str, Any]) -> None:
    print("## fk (batched forward kinematics)")
    print(f"bundled FR3: {r['poses_per_configuration']} poses per configuration (every joint, {len(r['frames'])} frames: "
          f"{', '.join(r['frames'])}); batch = {r['batch']} samples along a 0.5 rad segment; numpy agrees to "
          f"{r['numpy_max_difference']:.1e}")
    print(f"single, BatchFK.poses: {r['single_batchfk_us_median']:.2f} us median, {r['single_batchfk_us_p95']:.2f} us p95 "
          f"(target <= {TARGET_SINGLE_US} us: {_met(r['single_batchfk_us_median'], TARGET_SINGLE_US)})")
    print(f"single, BatchFK.poses allocating its output: {r['single_batchfk_allocating_us_median']:.2f} us median, "
          f"{r['single_batchfk_allocating_us_p95']:.2f} us p95")
    print(f"single, bare kernel from Python: {r['single_kernel_us_median']:.2f} us median, {r['single_kernel_us_p95']:.2f} us p95")
    print(f"single, Pinocchio FK + frame placements: {r['single_pinocchio_no_read_us_median']:.2f} us median without reading, "
          f"{r['single_pinocchio_read_us_median']:.2f} us median / {r['single_pinocchio_read_us_p95']:.2f} us p95 reading the "
          f"{len(r['frames'])} frames -> BatchFK {r['ratio_single_pinocchio_to_batchfk']:.1f}x faster")
    print(f"batch of {r['batch']}, BatchFK.poses_batch: {r['batch_batchfk_us_median']:.1f} us median, "
          f"{r['batch_batchfk_us_p95']:.1f} us p95, {r['batch_batchfk_us_median'] / r['batch']:.2f} us per configuration "
          f"(target <= {TARGET_BATCH_US} us: {_met(r['batch_batchfk_us_median'], TARGET_BATCH_US)})")
    print(f"batch of {r['batch']}, BatchFK.poses_batch allocating its output: {r['batch_batchfk_allocating_us_median']:.1f} us "
          f"median, {r['batch_batchfk_allocating_us_p95']:.1f} us p95")
    print(f"batch of {r['batch']}, numpy vectorised: {r['batch_numpy_us_median']:.1f} us median, {r['batch_numpy_us_p95']:.1f} us p95 "
          f"-> BatchFK {r['ratio_batch_numpy_to_batchfk']:.1f}x faster")
    print(f"batch of {r['batch']}, Pinocchio per configuration with reads: {r['batch_pinocchio_read_us_median']:.1f} us median, "
          f"{r['batch_pinocchio_read_us_p95']:.1f} us p95 -> BatchFK {r['ratio_batch_pinocchio_to_batchfk']:.1f}x faster "
          f"(target >= {TARGET_RATIO_TO_PINOCCHIO}x: "
          f"{_met(r['ratio_batch_pinocchio_to_batchfk'], TARGET_RATIO_TO_PINOCCHIO, at_least=True)})")
    print(f"batch of {r['batch']}, RobotModel.joint_frames (today's envelope path): "
          f"{r['batch_robotmodel_joint_frames_us_median']:.1f} us median")
    print(f"start-up: import numba {r['import_numba_s']:.2f} s; import batch_fk cold (compiles) {r['import_cold_s']:.2f} s, "
          f"warm (on-disk cache) {r['import_warm_s']:.2f} s")
