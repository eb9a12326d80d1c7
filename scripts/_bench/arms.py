"""Per-arm benchmark: the envelope's checks and the planners' time on every bundled arm's policy.

For each robot shipped in `src/armwarden/robots/` (found by listing, so a new folder is measured
with no edit here), its default bundled policy is loaded as `serve` loads it, and, from its home:

- the envelope: a state check and a straight-joint motion check as the detour search asks them
  (`check_path(..., first_only=True)`, random inputs within the limits), and the full check of a
  joint move of about 0.3 rad per joint;
- the planners: `plan_to_joints` to seeded goals near home, `plan_to_pose` to seeded TCP targets
  a few centimetres from home's TCP, each followed by the envelope's full check (what the Guard
  does), timed together.

Figures: medians and 95th percentiles in microseconds / milliseconds, and how many of the planned
requests were accepted by the envelope.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from armwarden.planning.planners import PoseTarget
from armwarden.policy import load_policy
from armwarden.preflight import load_runtime_model
from armwarden.robots import builtin_robots, load_profile

SEED = 27


def _us(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return (time.perf_counter() - start) * 1e6


def _p95(values: list[float]) -> float:
    return float(np.percentile(np.asarray(values), 95))


def bench_arm(robot_name: str, repeats: int = 200) -> dict[str, Any]:
    profile = load_profile(robot_name)
    policy_path = profile.file(next(iter(profile.policies.values())))
    runtime = load_runtime_model(load_policy(policy_path), str(policy_path))
    robot, envelope, planner = runtime.robot, runtime.envelope, runtime.planner
    limits = envelope.limits
    home = np.array(runtime.policy.robot.home_joint_positions)
    rng = np.random.default_rng(SEED)
    lower, upper = limits.lower_rad + limits.joint_limit_margin_rad, limits.upper_rad - limits.joint_limit_margin_rad
    states = rng.uniform(lower, upper, size=(repeats, robot.nq))
    motions = []
    for _ in range(repeats):
        start = rng.uniform(lower, upper)
        direction = rng.normal(size=robot.nq)
        motions.append(np.vstack([start, np.clip(start + direction / np.linalg.norm(direction) * rng.uniform(0, 1),
                                                 lower, upper)]))
    for q in states[:10]:  # warm-up
        envelope.check_path(q, first_only=True)
    state_us = [_us(lambda q=q: envelope.check_path(q, first_only=True)) for q in states]
    motion_us = [_us(lambda p=p: envelope.check_path(p, first_only=True)) for p in motions]
    goal = np.clip(home + 0.3 * np.sign(rng.normal(size=robot.nq)), lower, upper)
    typical = planner.plan_to_joints(home, goal, velocity_scaling=0.15).trajectory
    full_ms = []
    if typical is not None:
        plan = typical
        full_ms = [_us(lambda: envelope.check(plan)) / 1e3 for _ in range(max(20, repeats // 10))]

    joint_ms, joint_ok, pose_ms, pose_ok = [], 0, [], 0
    tcp = robot.tcp_pose(home)
    for _ in range(max(20, repeats // 10)):
        target = np.clip(home + rng.uniform(-0.25, 0.25, size=robot.nq), lower, upper)
        start = time.perf_counter()
        outcome = planner.plan_to_joints(home, target)
        accepted = outcome.trajectory is not None and not envelope.check(outcome.trajectory).hard
        joint_ms.append((time.perf_counter() - start) * 1e3)
        joint_ok += accepted
        position = tcp.position + rng.uniform(-0.05, 0.05, size=3)
        start = time.perf_counter()
        outcome = planner.plan_to_pose(home, PoseTarget(position, tcp.rotation))
        accepted = outcome.trajectory is not None and not envelope.check(outcome.trajectory).hard
        pose_ms.append((time.perf_counter() - start) * 1e3)
        pose_ok += accepted
    med = statistics.median
    return {
        "joints": robot.nq, "capsules": len(robot.capsules), "self_collision_pairs": len(envelope.self_collision_pairs),
        "state_us_median": med(state_us), "state_us_p95": _p95(state_us),
        "motion_us_median": med(motion_us), "motion_us_p95": _p95(motion_us),
        "full_ms_median": med(full_ms) if full_ms else None, "full_ms_p95": _p95(full_ms) if full_ms else None,
        "plan_joints_ms_median": med(joint_ms), "plan_joints_ms_p95": _p95(joint_ms),
        "plan_joints_accepted": f"{joint_ok}/{len(joint_ms)}",
        "plan_pose_ms_median": med(pose_ms), "plan_pose_ms_p95": _p95(pose_ms), "plan_pose_accepted": f"{pose_ok}/{len(pose_ms)}",
    }


def bench_arms() -> dict[str, Any]:
    return {name: bench_arm(name) for name in builtin_robots()}


def report_arms(results: dict[str, Any]) -> None:
    print("## arms (envelope check and planning time per bundled arm)")
    print("| arm | joints | capsules | pairs | state check µs p50/p95 | motion check µs p50/p95 | full check ms p50/p95 "
          "| plan_to_joints ms p50/p95 (accepted) | plan_to_pose ms p50/p95 (accepted) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        full = f"{r['full_ms_median']:.2f} / {r['full_ms_p95']:.2f}" if r["full_ms_median"] is not None else "—"
        print(f"| {name} | {r['joints']} | {r['capsules']} | {r['self_collision_pairs']} "
              f"| {r['state_us_median']:.0f} / {r['state_us_p95']:.0f} | {r['motion_us_median']:.0f} / {r['motion_us_p95']:.0f} "
              f"| {full} | {r['plan_joints_ms_median']:.2f} / {r['plan_joints_ms_p95']:.2f} ({r['plan_joints_accepted']}) "
              f"| {r['plan_pose_ms_median']:.2f} / {r['plan_pose_ms_p95']:.2f} ({r['plan_pose_accepted']}) |")
