"""Planner benchmark: scenes around obstacles, the detour planner beside the straight-line planner.

Two sets, both on the bundled FR3 policy (its monitor and camera-mast zones stay in), start at
the ready pose:

- the scene set: an open bin in front (targets inside), a shelf (targets between its boards), a
  wall-like zone (targets behind it) and targets near the robot's own body;
- the near-obstacle set: one bin-sized box on the table in front, TCP targets 2–10 cm outside its
  top and side faces (seeded), half of them with the hand pointing down, half position-only.

For every target both planners run in the same process, one after the other, through the same
`plan_and_check` the Guard uses (straight line = `detours` switched off), and the verdict is the
envelope's. "Has a goal" means some IK solution from 66 seeds (start, home, 64 random) passes the
envelope's static checks; "arrivable" that one of them is also clear with the largest sweep
allowance the final check can give a plan's last sample, so that no zone makes the final check
refuse a plan at its last sample there (see `goal_kind`; a target without such a goal may still
be solved); "within the caps" that one plan can
reach the target under the per-plan caps (see `within_caps`). The solved fraction is reported
among these and overall; the TCP path ratio only where the straight line was refused.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from armwarden.guard.planning import plan_and_check
from armwarden.planning.around import DetourPlanner
from armwarden.planning.goals import ARRIVAL_SHARES
from armwarden.planning.planners import PoseTarget
from armwarden.policy import bundled_policy, load_policy
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.safety.envelope import Box, Envelope

READY = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
DOWN = np.diag([1.0, -1.0, -1.0])  # the tool pointing at the table
DOWN_TURNED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # pointing down, fingers along x
FORWARD = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # the tool pointing away from the base (+x)


@dataclass(frozen=True)
class Scene:
    name: str
    zones: tuple[Box, ...]
    targets: tuple[PoseTarget, ...]
    start: np.ndarray = dataclasses.field(default_factory=READY.copy)


def _box(name: str, lo: list[float], hi: list[float]) -> Box:
    return Box.of(name, lo, hi)


def scene_set() -> tuple[Scene, ...]:
    """Four hand-made scenes a table-top arm meets."""
    bin_walls = (  # an open bin, 40 × 40 × 18 cm outside, 2 cm walls, in front of the robot
        _box("bin_back", [0.35, -0.20, 0.0], [0.37, 0.20, 0.18]),
        _box("bin_front", [0.73, -0.20, 0.0], [0.75, 0.20, 0.18]),
        _box("bin_left", [0.35, 0.18, 0.0], [0.75, 0.20, 0.18]),
        _box("bin_right", [0.35, -0.20, 0.0], [0.75, -0.18, 0.18]),
    )
    shelf = (  # a shelf compartment open towards the robot, 30 cm deep, boards at 25 and 55 cm
        _box("shelf_bottom", [0.50, -0.30, 0.23], [0.80, 0.10, 0.25]),
        _box("shelf_top", [0.50, -0.30, 0.55], [0.80, 0.10, 0.57]),
        _box("shelf_back", [0.80, -0.30, 0.23], [0.82, 0.10, 0.57]),
        _box("shelf_left", [0.50, 0.08, 0.23], [0.80, 0.10, 0.57]),
        _box("shelf_right", [0.50, -0.30, 0.23], [0.80, -0.28, 0.57]),
    )
    wall = (_box("wall", [0.45, -0.30, 0.0], [0.48, 0.30, 0.40]),)
    return (
        Scene("bin in front", bin_walls, (
            PoseTarget(np.array([0.55, 0.0, 0.10]), DOWN_TURNED),
            PoseTarget(np.array([0.50, 0.06, 0.08]), DOWN_TURNED),
            PoseTarget(np.array([0.62, -0.06, 0.12]), DOWN),
            PoseTarget(np.array([0.58, 0.05, 0.07])),
            PoseTarget(np.array([0.45, -0.08, 0.10])),
        )),
        Scene("shelf", shelf, (
            PoseTarget(np.array([0.62, -0.10, 0.40]), FORWARD),
            PoseTarget(np.array([0.58, -0.15, 0.35]), FORWARD),
            PoseTarget(np.array([0.65, -0.05, 0.42])),
            PoseTarget(np.array([0.60, -0.12, 0.32])),
        )),
        Scene("behind a wall", wall, (
            PoseTarget(np.array([0.60, 0.0, 0.15]), DOWN),
            PoseTarget(np.array([0.62, 0.12, 0.20]), DOWN),
            PoseTarget(np.array([0.58, -0.15, 0.12]), DOWN),
            PoseTarget(np.array([0.65, 0.05, 0.25])),
        )),
        Scene("near the body", (), (
            PoseTarget(np.array([0.22, 0.15, 0.15]), DOWN),
            PoseTarget(np.array([0.18, -0.22, 0.25]), DOWN),
            PoseTarget(np.array([0.05, 0.30, 0.30])),
            PoseTarget(np.array([-0.10, 0.30, 0.35]), DOWN),
            PoseTarget(np.array([0.25, 0.0, 0.10]), DOWN),
        )),
    )


NEAR_BOX = _box("bin_box", [0.40, -0.20, 0.0], [0.70, 0.20, 0.25])


def near_obstacle_set(n_targets: int = 40, seed: int = 12) -> Scene:
    """A bin-sized box on the table in front; TCP targets 2–10 cm outside its top and side faces."""
    rng = np.random.default_rng(seed)
    lo, hi = NEAR_BOX.lo, NEAR_BOX.hi
    targets = []
    faces = ("top", "front", "back", "left", "right")
    for k in range(n_targets):
        face = faces[k % len(faces)]
        gap = rng.uniform(0.02, 0.10)
        p = np.array([rng.uniform(lo[0] + 0.03, hi[0] - 0.03), rng.uniform(lo[1] + 0.03, hi[1] - 0.03),
                      rng.uniform(0.06, hi[2] - 0.02)])
        if face == "top":
            p[2] = hi[2] + gap
        elif face == "front":
            p[0] = hi[0] + gap
        elif face == "back":
            p[0] = lo[0] - gap
        elif face == "left":
            p[1] = hi[1] + gap
        else:
            p[1] = lo[1] - gap
        targets.append(PoseTarget(p, DOWN if k % 2 == 0 else None))
    return Scene("near-obstacle set", (NEAR_BOX,), tuple(targets))


# ------------------------------------------------------------------------------------ models
def runtime_for(base: RuntimeModel, zones: tuple[Box, ...], budget_s: float | None = None) -> tuple[RuntimeModel, RuntimeModel]:
    """(with detours, straight lines only) for the policy's zones plus `zones`."""
    envelope = Envelope(base.robot, dataclasses.replace(base.envelope.limits, keep_out=base.envelope.limits.keep_out + zones))
    budget = base.policy.motion.planning_time_s if budget_s is None else budget_s
    detours = DetourPlanner(base.planner, envelope, budget)
    with_detours = dataclasses.replace(base, envelope=envelope, detours=detours)
    return with_detours, dataclasses.replace(with_detours, detours=None)


def goal_kind(model: RuntimeModel, start: np.ndarray, target: PoseTarget, seeds: int = 64) -> str:
    """"none": no IK solution from 66 seeds passes the envelope's static checks; "close": some do,
    but none is clear once its bodies grow by the largest sweep allowance the final check can give
    a plan's last sample (`Envelope.check_arrival`, share 0.5: whether a plan can end there
    depends on the motion into it); "arrivable": one is (no zone refuses a plan at its last
    sample there). A "close" target may still be solved: this is a likelihood, not a bound."""
    rng = np.random.default_rng(99)
    robot, ik, envelope = model.robot, model.planner.ik, model.envelope
    kind = "none"
    for seed_q in [start, model.planner.settings.home_rad] + [rng.uniform(robot.lower, robot.upper) for _ in range(seeds)]:
        result = ik.solve_from(target.position, target.rotation, seed_q)
        if not result.success or any(v.is_hard for v in envelope.check_path(result.q)):
            continue
        kind = "close"
        if not any(v.is_hard for v in envelope.check_arrival(result.q, ARRIVAL_SHARES[0])):
            return "arrivable"
    return kind


def within_caps(model: RuntimeModel, start: np.ndarray, target: PoseTarget, seeds: int = 254) -> bool:
    """Whether one plan from `start` can reach `target` under the policy's per-plan caps at all,
    by two necessary conditions: the straight TCP distance is within the TCP path cap (no path is
    shorter), and some collision-free goal configuration lies within the joint travel cap of
    `start` in every joint (no path travels less). Goals are sought by IK from the start, home and
    `seeds` configurations within the travel cap around the start. False: no planner could solve
    the target in one plan, whatever it does."""
    limits, robot, ik = model.envelope.limits, model.robot, model.planner.ik
    if np.linalg.norm(target.position - robot.tcp_pose(start).position) > limits.max_cartesian_step_m:
        return False
    cap = limits.max_joint_step_rad
    rng = np.random.default_rng(98)
    around = [np.clip(start + rng.uniform(-cap, cap, robot.nq), robot.lower, robot.upper) for _ in range(seeds)]
    for seed_q in [start, model.planner.settings.home_rad, *around]:
        result = ik.solve_from(target.position, target.rotation, seed_q)
        if (result.success and np.max(np.abs(result.q - start)) <= cap
                and not any(v.is_hard for v in model.envelope.check_path(result.q))):
            return True
    return False


def run_target(model: RuntimeModel, start: np.ndarray, target: PoseTarget) -> dict[str, Any]:
    began = time.perf_counter()
    outcome, report = plan_and_check(model, "pose", start, {"target": target})
    elapsed = time.perf_counter() - began
    solved = report is not None and not report.hard and outcome.trajectory is not None
    codes = sorted({v.code.value for v in (*outcome.violations, *(report.violations if report else ())) if v.is_hard})
    return {"solved": solved, "time_s": elapsed, "tcp_path_m": report.tcp_path_length_m if report else None,
            "codes": codes, "trajectory": outcome.trajectory if solved else None}


def run_scene(base: RuntimeModel, scene: Scene) -> list[dict[str, Any]]:
    ours, straight = runtime_for(base, scene.zones)
    rows = []
    for target in scene.targets:
        rows.append({
            "scene": scene.name,
            "goal": goal_kind(ours, scene.start, target),
            "within_caps": within_caps(ours, scene.start, target),
            "straight": run_target(straight, scene.start, target),
            "detour": run_target(ours, scene.start, target),
        })
    return rows


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    with_goal = [r for r in rows if r["goal"] != "none"]
    arrivable = [r for r in rows if r["goal"] == "arrivable"]
    reachable = [r for r in with_goal if r["within_caps"]]
    fair = [r for r in arrivable if r["within_caps"]]  # within the caps, and a goal no zone refuses at a plan's end
    out: dict[str, Any] = {"targets": len(rows), "with_goal": len(with_goal), "arrivable": len(arrivable),
                           "within_caps": len(reachable), "arrivable_within_caps": len(fair)}
    for name in ("straight", "detour"):
        solved = [r for r in rows if r[name]["solved"]]
        times_ms = [r[name]["time_s"] * 1e3 for r in rows]
        # path length: only where the straight line was refused (elsewhere both plans are the same one)
        ratios = [r[name]["tcp_path_m"] / r["straight"]["tcp_path_m"] for r in solved
                  if r["straight"]["tcp_path_m"] and not r["straight"]["solved"]]
        out[name] = {  # the "straight" planner is plan_and_check with detours off
            "solved": len(solved),
            "solved_with_goal": sum(r[name]["solved"] for r in with_goal),
            "solved_fraction_with_goal": (sum(r[name]["solved"] for r in with_goal) / len(with_goal)) if with_goal else float("nan"),
            "solved_fraction": len(solved) / len(rows) if rows else float("nan"),
            "solved_arrivable": sum(r[name]["solved"] for r in arrivable),
            "solved_within_caps": sum(r[name]["solved"] for r in reachable),
            "solved_arrivable_within_caps": sum(r[name]["solved"] for r in fair),
            "solved_fraction_arrivable_within_caps": (sum(r[name]["solved"] for r in fair) / len(fair))
            if fair else float("nan"),
            "time_ms_median": statistics.median(times_ms) if times_ms else float("nan"),
            "time_ms_p95": float(np.percentile(times_ms, 95)) if times_ms else float("nan"),
            "path_ratio_median": statistics.median(ratios) if ratios else float("nan"),
            "path_ratio_max": max(ratios) if ratios else float("nan"),
        }
    out["blocked_codes_straight"] = sorted({c for r in rows if not r["straight"]["solved"] for c in r["straight"]["codes"]})
    out["unsolved_codes_detour"] = sorted({c for r in rows if not r["detour"]["solved"] for c in r["detour"]["codes"]})
    return out


#: the per-plan caps of the "caps raised" runs: the bundled policy allows 0.5 m of TCP path and 1.5 rad
#: per joint in one plan, which many detours around a bin-sized box exceed whatever the planner does
RAISED_CAPS = {"max_cartesian_step_m": 1.5, "max_joint_step_rad": 3.14}


#: the finer sweep resolution of the last run [m]: the final check gives a plan's last sample at
#: most half of it, so goals a few millimetres from the box become arrivable
FINER_SWEEP_RESOLUTION_M = 0.005


def with_raised_caps(base: RuntimeModel, sweep_resolution_m: float | None = None) -> RuntimeModel:
    limits = dataclasses.replace(base.envelope.limits, **RAISED_CAPS)
    if sweep_resolution_m is not None:
        limits = dataclasses.replace(limits, sweep_resolution_m=sweep_resolution_m)
    return dataclasses.replace(base, envelope=Envelope(base.robot, limits))


def bench_planner() -> dict[str, Any]:
    base = load_runtime_model(load_policy(bundled_policy("fr3")))
    results: dict[str, Any] = {"budget_s": base.policy.motion.planning_time_s, "scenes": {}, "raised_caps": RAISED_CAPS}
    all_rows: list[dict[str, Any]] = []
    for scene in scene_set():
        rows = run_scene(base, scene)
        all_rows += rows
        results["scenes"][scene.name] = summarise(rows)
    results["scene_set"] = summarise(all_rows)
    results["near_obstacle"] = summarise(run_scene(base, near_obstacle_set()))
    raised = with_raised_caps(base)
    results["scene_set_raised_caps"] = summarise([row for scene in scene_set() for row in run_scene(raised, scene)])
    results["near_obstacle_raised_caps"] = summarise(run_scene(raised, near_obstacle_set()))
    finer = with_raised_caps(base, FINER_SWEEP_RESOLUTION_M)
    results["finer_sweep_resolution_m"] = FINER_SWEEP_RESOLUTION_M
    results["near_obstacle_raised_caps_finer"] = summarise(run_scene(finer, near_obstacle_set()))
    return results


def report_planner(r: dict[str, Any]) -> None:
    print("## planner (straight line vs detour; both through plan_and_check, the envelope decides)")
    print(f"planning budget (motion.planning_time_s): {r['budget_s']:g} s; start: the ready pose")

    def block(title: str, s: dict[str, Any], goal: bool) -> None:
        print(f"{title}: {s['targets']} targets, {s['with_goal']} with a collision-free goal configuration, "
              f"{s['arrivable']} of them arrivable (a goal clear with the largest sweep allowance of a plan's last sample), "
              f"{s['within_caps']} of them within the per-plan caps (straight TCP distance and some goal's joint travel), "
              f"{s['arrivable_within_caps']} both")
        for name in ("straight", "detour"):
            f = s[name]
            verdicts = ""
            if goal and name == "detour":
                verdicts = (f"  [goals: solved-with-goal >= 90 %: {'met' if f['solved_fraction_with_goal'] >= 0.9 else 'MISSED'}; "
                            f"median <= 50 ms: {'met' if f['time_ms_median'] <= 50 else 'MISSED'}; "
                            f"p95 <= 500 ms: {'met' if f['time_ms_p95'] <= 500 else 'MISSED'}]")
            print(f"  {name:8s} solved {f['solved_with_goal']}/{s['with_goal']} with a goal "
                  f"({100 * f['solved_fraction_with_goal']:.0f} %), {f['solved']}/{s['targets']} overall "
                  f"({100 * f['solved_fraction']:.0f} %), {f['solved_arrivable']}/{s['arrivable']} arrivable, "
                  f"{f['solved_within_caps']}/{s['within_caps']} within the caps, "
                  f"{f['solved_arrivable_within_caps']}/{s['arrivable_within_caps']} both "
                  f"({100 * f['solved_fraction_arrivable_within_caps']:.0f} %); "
                  f"time median {f['time_ms_median']:.1f} ms, p95 {f['time_ms_p95']:.1f} ms; "
                  f"TCP path / the refused straight line's: median {f['path_ratio_median']:.2f}, max {f['path_ratio_max']:.2f}{verdicts}")
        print(f"  straight line blocked by: {', '.join(s['blocked_codes_straight']) or '-'}; "
              f"detour unsolved with: {', '.join(s['unsolved_codes_detour']) or '-'}")

    for name, s in r["scenes"].items():
        block(f"scene '{name}'", s, False)
    block("scene set, all scenes", r["scene_set"], False)
    block("near-obstacle set (bin-sized box, targets 2-10 cm outside its faces)", r["near_obstacle"], True)
    caps = ", ".join(f"{k} {v:g}" for k, v in r["raised_caps"].items())
    block(f"scene set, per-plan caps raised ({caps})", r["scene_set_raised_caps"], False)
    block(f"near-obstacle set, per-plan caps raised ({caps})", r["near_obstacle_raised_caps"], True)
    block(f"near-obstacle set, per-plan caps raised and motion.sweep_resolution_m {r['finer_sweep_resolution_m']:g} m "
          "(the bundled policy's: 0.01 m)", r["near_obstacle_raised_caps_finer"], True)
