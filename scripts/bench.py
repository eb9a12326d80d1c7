#!/usr/bin/env python3
"""ArmWarden benchmarks: every figure is a ratio or a percentile measured in this one run.

    python scripts/bench.py                 # all sections
    python scripts/bench.py envelope        # one section
    python scripts/bench.py --json out.json # also write the raw figures

Sections
- envelope: cost of the full envelope check (every link, self-collision, keep-out, workspace)
  on a typical 0.5 rad, ~1.5 s FR3 plan, against bare Pinocchio FK over the same samples.

Timing thresholds live here, never in unit tests: the machines are shared and noisy. Each
target is reported as met or missed; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from armwarden.cli import bundled_policy  # noqa: E402
from armwarden.policy import load_policy  # noqa: E402
from armwarden.preflight import load_runtime_model  # noqa: E402

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
    import pinocchio as pin

    runtime = load_runtime_model(load_policy(bundled_policy("fr3")))
    robot, envelope, planner = runtime.robot, runtime.envelope, runtime.planner
    trajectory = planner.plan_to_joints(READY, READY + TYPICAL_DELTA, velocity_scaling=0.15).trajectory
    report = envelope.check(trajectory)
    assert not report.violations, report.violations
    _, q_samples, _ = envelope.sample_path(trajectory.times, trajectory.positions)
    model, data = robot.model, robot.data
    tcp_id = model.getFrameId(robot.tcp_frame)

    def bare_fk_tcp() -> None:
        for q in q_samples:
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacement(model, data, tcp_id).translation  # noqa: B018 - read it, as a check must

    def bare_fk_bodies() -> None:
        robot.joint_frames(q_samples)

    def full_check() -> None:
        envelope.check(trajectory)

    # interleave the three so that machine noise hits them alike
    full, tcp, bodies = [], [], []
    for _ in range(repeats):
        full += _time_us(full_check, 1)
        tcp += _time_us(bare_fk_tcp, 1)
        bodies += _time_us(bare_fk_bodies, 1)
    n = len(q_samples)
    full_med, tcp_med, bodies_med = statistics.median(full), statistics.median(tcp), statistics.median(bodies)
    return {
        "plan_duration_s": trajectory.duration_s,
        "plan_waypoints": len(trajectory.times),
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
        f"{r['checked_samples']} conservative geometry samples, {r['capsules']} capsules + TCP, "
        f"{r['self_collision_pairs']} self-collision pairs, {r['keep_out_zones']} keep-out zones"
    )
    print(f"full check: {r['full_check_ms_median']:.3f} ms median, {r['full_check_ms_p95']:.3f} ms p95  "
          f"(target < 2 ms: {'met' if r['full_check_ms_median'] < 2 else 'MISSED'})")
    print(f"checked samples per second: {r['checked_samples_per_s']:,.0f}")
    print(f"bare FK + TCP read over the same samples: {r['bare_fk_tcp_us_median']:.0f} us -> ratio "
          f"{r['ratio_full_to_fk_tcp']:.2f}x (target <= 3x: {'met' if r['ratio_full_to_fk_tcp'] <= 3 else 'MISSED'})")
    print(f"bare FK + every checked body's placement: {r['bare_fk_bodies_us_median']:.0f} us -> ratio "
          f"{r['ratio_full_to_fk_bodies']:.2f}x")


SECTIONS = {"envelope": (bench_envelope, _report_envelope)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sections", nargs="*", choices=[*SECTIONS, []], default=[])
    parser.add_argument("--json", default=None, help="write the raw figures to this file")
    args = parser.parse_args()
    chosen = args.sections or list(SECTIONS)
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
