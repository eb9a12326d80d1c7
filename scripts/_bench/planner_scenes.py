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
be solved); "within the caps" that two necessary conditions for one plan under the per-plan caps
hold (see `within_caps`): a target that fails them no planner can solve.

"Solvable" (the denominator of the near-obstacle target) is proven by construction: some planner
produced a plan the envelope accepts — the straight-line planner, the detour planner at the
policy's budget, or, for targets within the caps that neither solved, the same detour planner
with `REFERENCE_BUDGET_FACTOR` times the budget and `REFERENCE_GOALS` (four times the goal
seeds), or an independent one (`ompl_reference`: OMPL's RRTConnect, which knows nothing of the
caps, for `OMPL_BUDGET_S` to the goals of `OMPL_GOAL_SEEDS` IK seeds). Targets within the caps
that none of them solved are "open" (neither proven solvable nor proven unsolvable) and are
counted and named, never silently dropped. The solved fraction is reported among each of these
sets and overall; planning time over the solvable targets and over all; how each target was
solved; the TCP path ratio only where the straight line was refused.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from armwarden.guard.planning import plan_and_check
from armwarden.planning.around import DetourPlanner
from armwarden.planning.goals import ARRIVAL_SHARES, GoalOptions, GoalSelector
from armwarden.planning.planners import PoseTarget
from armwarden.planning.timing import TimingError, time_parameterize
from armwarden.policy import bundled_policy, load_policy
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import Box

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
    shorter: a proof), and some collision-free goal configuration lies within the joint travel
    cap of `start` in every joint (no path travels less). Goals are sought by IK from the start,
    home and `seeds` configurations within the travel cap around the start, then by the detour
    planner's goal selection with the reference run's seeds (`REFERENCE_GOALS`, which also turns
    the hand about the tool axis), from the straight-line planner's solution, four times: a sampled search, so "no goal" is strong evidence,
    not a proof. False: no planner could solve the target in one plan, whatever it does."""
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
    chooser = GoalSelector(ik, model.envelope, model.planner.settings.home_rad, REFERENCE_GOALS)
    straight = model.planner.plan_to_pose(start, target).trajectory  # the solution the planner starts from
    first = None if straight is None else straight.goal
    return any(chooser.select(start, target.position, target.rotation, seed=seed, deadline=time.monotonic() + 60.0,
                              first=first, free_yaw=target.free_yaw).goals for seed in range(98, 102))


def run_target(model: RuntimeModel, start: np.ndarray, target: PoseTarget) -> dict[str, Any]:
    began = time.perf_counter()
    outcome, report = plan_and_check(model, "pose", start, {"target": target})
    elapsed = time.perf_counter() - began
    solved = report is not None and not report.hard and outcome.trajectory is not None
    codes = sorted({v.code.value for v in (*outcome.violations, *(report.violations if report else ())) if v.is_hard})
    return {"solved": solved, "time_s": elapsed, "tcp_path_m": report.tcp_path_length_m if report else None,
            "codes": codes, "trajectory": outcome.trajectory if solved else None, "how": _how(outcome.notes) if solved else None}


#: what a detour note says, and the name the benchmark counts it under
_HOW = (("straight TCP line", "TCP line"), ("clear line to a collision-free goal", "line to another goal"),
        ("joint-space search", "search"))


def _how(notes: tuple[str, ...]) -> str:
    """How a solved target was solved: the straight joint line, or which kind of detour."""
    for note in notes:
        for phrase, name in _HOW:
            if note.startswith("detour planned") and phrase in note:
                return name
    return "straight joint line"


#: the reference run (`reference_model`): this many times the policy's planning budget
REFERENCE_BUDGET_FACTOR = 20
#: and this goal selection: four times the seeds, twice the goals
REFERENCE_GOALS = GoalOptions(local_seeds=32, random_seeds=32, extra_seeds=64, max_goals=8)


def reference_model(model: RuntimeModel) -> RuntimeModel:
    """`model`'s detour planner with `REFERENCE_BUDGET_FACTOR` times the budget and `REFERENCE_GOALS`."""
    assert model.detours is not None
    planner, envelope = model.planner, model.envelope
    goals = GoalSelector(planner.ik, envelope, planner.settings.home_rad, REFERENCE_GOALS)
    return dataclasses.replace(model, detours=DetourPlanner(planner, envelope, model.detours.budget_s * REFERENCE_BUDGET_FACTOR,
                                                           goals=goals))


#: the independent reference (`ompl_reference`): its budget per target [s] and its IK seeds for goals
OMPL_BUDGET_S = 10.0
OMPL_GOAL_SEEDS = 400


def ompl_reference(model: RuntimeModel, start: np.ndarray, target: PoseTarget, budget_s: float = OMPL_BUDGET_S,
                   seeds: int = OMPL_GOAL_SEEDS) -> bool:
    """Whether an independent planner finds a plan the envelope accepts: OMPL's RRTConnect (the
    search ArmWarden used before, which knows nothing of the caps) from `start` to every
    collision-free IK solution within the travel cap (from `seeds` seeds around the start), trees
    restarted every second, each path shortened by OMPL's own simplifier, timed and checked by
    `Envelope.check` like any plan. Shares only the envelope and IK with the planner it checks."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    envelope, robot, ik, settings = model.envelope, model.robot, model.planner.ik, model.planner.settings
    cap = envelope.limits.max_joint_step_rad
    rng = np.random.default_rng(97)
    goals: list[np.ndarray] = []
    for seed_q in [start, settings.home_rad] + [np.clip(start + rng.uniform(-cap, cap, robot.nq), robot.lower, robot.upper)
                                                for _ in range(seeds)]:
        result = ik.solve_from(target.position, target.rotation, seed_q)
        if (result.success and np.max(np.abs(result.q - start)) <= cap
                and not any(v.is_hard for v in envelope.check_path(result.q, first_only=True))
                and all(np.max(np.abs(result.q - g)) > 0.05 for g in goals)):
            goals.append(result.q)
    if not goals:
        return False
    n = robot.nq
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    every = np.vstack([start, *goals])
    lower = np.minimum(np.maximum(robot.lower, start - cap), every.min(axis=0))
    upper = np.maximum(np.minimum(robot.upper, start + cap), every.max(axis=0))
    for i in range(n):
        bounds.setLow(i, float(lower[i]))
        bounds.setHigh(i, float(upper[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)

    def array(state: Any) -> np.ndarray:
        return np.array([state[i] for i in range(n)])

    def clear(*qs: np.ndarray) -> bool:
        return not any(v.is_hard for v in envelope.check_path(np.vstack(qs), first_only=True))

    class Motions(ob.MotionValidator):
        def checkMotion(self, s1: Any, s2: Any, *last_valid: Any) -> bool:
            return clear(array(s1), array(s2))

    si.setStateValidityChecker(lambda state: clear(array(state)))
    motions = Motions(si)  # kept referenced: OMPL holds it by a raw pointer
    si.setMotionValidator(motions)
    si.setup()
    deadline = time.monotonic() + budget_s
    while (remaining := deadline - time.monotonic()) > 0:
        problem = ob.ProblemDefinition(si)
        problem.addStartState(_ompl_state(si, start))
        goal_states = ob.GoalStates(si)
        for goal in goals:
            goal_states.addState(_ompl_state(si, goal))
        problem.setGoal(goal_states)
        planner = og.RRTConnect(si)
        planner.setRange(0.5)
        planner.setProblemDefinition(problem)
        planner.setup()
        planner.solve(min(remaining, 1.0))
        if not problem.hasExactSolution():
            continue
        path: Any = problem.getSolutionPath()  # a geometric planner's: a PathGeometric
        og.PathSimplifier(si).simplifyMax(path)
        positions = np.vstack([array(path.getState(i)) for i in range(path.getStateCount())])
        positions[0] = start
        try:
            trajectory = time_parameterize(robot.joint_names, positions,
                                           settings.max_velocity_rad_s * settings.default_velocity_scaling,
                                           settings.max_acceleration_rad_s2 * settings.default_acceleration_scaling,
                                           stops=tuple(range(1, len(positions) - 1)))
        except TimingError:
            continue
        if not envelope.check(trajectory).hard:
            return True
    return False


def _ompl_state(si: Any, q: np.ndarray) -> Any:
    state = si.allocState()
    for i, value in enumerate(q):
        state[i] = float(value)
    return state


def run_scene(base: RuntimeModel, scene: Scene, reference_run: bool = False) -> list[dict[str, Any]]:
    """Every target of `scene` through both planners; with `reference_run`, the targets within the
    caps that neither solved through the reference planner too (`reference_model`)."""
    ours, straight = runtime_for(base, scene.zones)
    reference = reference_model(ours)
    rows = []
    for target in scene.targets:
        row = {
            "scene": scene.name,
            "target": target,
            "goal": goal_kind(ours, scene.start, target),
            "within_caps": within_caps(ours, scene.start, target),
            "straight": run_target(straight, scene.start, target),
            "detour": run_target(ours, scene.start, target),
        }
        solved = row["straight"]["solved"] or row["detour"]["solved"]
        row["reference"] = (run_target(reference, scene.start, target)["solved"]
                            if reference_run and not solved and row["within_caps"] else None)
        row["ompl"] = (ompl_reference(ours, scene.start, target)
                       if reference_run and not solved and row["within_caps"] else None)
        row["solvable"] = solved or bool(row["reference"]) or bool(row["ompl"])
        rows.append(row)
    return rows


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    # within the caps implies a goal: `within_caps` seeks goals harder than `goal_kind`
    with_goal = [r for r in rows if r["goal"] != "none" or r["within_caps"]]
    arrivable = [r for r in rows if r["goal"] == "arrivable"]
    reachable = [r for r in rows if r["within_caps"]]
    fair = [r for r in arrivable if r["within_caps"]]  # within the caps, and a goal no zone refuses at a plan's end
    solvable = [r for r in rows if r["solvable"]]
    out: dict[str, Any] = {"targets": len(rows), "with_goal": len(with_goal), "arrivable": len(arrivable),
                           "within_caps": len(reachable), "arrivable_within_caps": len(fair),
                           "solvable": len(solvable), "solvable_outside_caps": sum(not r["within_caps"] for r in solvable),
                           "open": [_describe(r["target"]) for r in reachable if not r["solvable"]]}
    for name in ("straight", "detour"):
        solved = [r for r in rows if r[name]["solved"]]
        times_ms = [r[name]["time_s"] * 1e3 for r in rows]
        solvable_ms = [r[name]["time_s"] * 1e3 for r in solvable]
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
            "solved_solvable": sum(r[name]["solved"] for r in solvable),
            "how": dict(sorted(Counter(r[name]["how"] for r in solved).items())),
            "solved_fraction_solvable": (sum(r[name]["solved"] for r in solvable) / len(solvable))
            if solvable else float("nan"),
            "time_ms_median": statistics.median(times_ms) if times_ms else float("nan"),
            "time_ms_p95": float(np.percentile(times_ms, 95)) if times_ms else float("nan"),
            "time_ms_median_solvable": statistics.median(solvable_ms) if solvable_ms else float("nan"),
            "time_ms_p95_solvable": float(np.percentile(solvable_ms, 95)) if solvable_ms else float("nan"),
            "time_ms_max_solvable": max(solvable_ms) if solvable_ms else float("nan"),
            "path_ratio_median": statistics.median(ratios) if ratios else float("nan"),
            "path_ratio_max": max(ratios) if ratios else float("nan"),
        }
    out["blocked_codes_straight"] = sorted({c for r in rows if not r["straight"]["solved"] for c in r["straight"]["codes"]})
    out["unsolved_codes_detour"] = sorted({c for r in rows if not r["detour"]["solved"] for c in r["detour"]["codes"]})
    return out


def _describe(target: PoseTarget) -> str:
    p = target.position
    return f"({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) {'hand down' if target.rotation is not None else 'position only'}"


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
    results["near_obstacle"] = summarise(run_scene(base, near_obstacle_set(), reference_run=True))
    results["reference"] = {"budget_factor": REFERENCE_BUDGET_FACTOR, "goals": dataclasses.asdict(REFERENCE_GOALS),
                            "ompl_budget_s": OMPL_BUDGET_S, "ompl_goal_seeds": OMPL_GOAL_SEEDS}
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

    def block(title: str, s: dict[str, Any]) -> None:
        print(f"{title}: {s['targets']} targets, {s['with_goal']} with a collision-free goal configuration, "
              f"{s['arrivable']} of them arrivable (a goal clear with the largest sweep allowance of a plan's last sample), "
              f"{s['within_caps']} within the per-plan caps' necessary conditions (straight TCP distance and some goal's "
              f"joint travel), {s['arrivable_within_caps']} both")
        for name in ("straight", "detour"):
            f = s[name]
            print(f"  {name:8s} solved {f['solved_with_goal']}/{s['with_goal']} with a goal "
                  f"({100 * f['solved_fraction_with_goal']:.0f} %), {f['solved']}/{s['targets']} overall "
                  f"({100 * f['solved_fraction']:.0f} %), {f['solved_arrivable']}/{s['arrivable']} arrivable, "
                  f"{f['solved_within_caps']}/{s['within_caps']} within the caps, "
                  f"{f['solved_arrivable_within_caps']}/{s['arrivable_within_caps']} both; "
                  f"time median {f['time_ms_median']:.1f} ms, p95 {f['time_ms_p95']:.1f} ms (all targets); "
                  f"TCP path / the refused straight line's: median {f['path_ratio_median']:.2f}, max {f['path_ratio_max']:.2f}; "
                  f"solved by: {', '.join(f'{how} {count}' for how, count in f['how'].items()) or '-'}")
        print(f"  straight line blocked by: {', '.join(s['blocked_codes_straight']) or '-'}; "
              f"detour unsolved with: {', '.join(s['unsolved_codes_detour']) or '-'}")

    def target(s: dict[str, Any]) -> None:
        f = s["detour"]
        ref = r["reference"]
        print(f"  TARGET near-obstacle set: solvable = {s['solvable']} targets (a plan the envelope accepts was found by "
              f"the straight-line planner, the detour planner, the detour planner with {ref['budget_factor']}x the "
              f"budget and 4x the goal seeds, or OMPL's RRTConnect for {ref['ompl_budget_s']:g} s to the goals of "
              f"{ref['ompl_goal_seeds']} IK seeds; {s['solvable_outside_caps']} of them outside the caps' necessary "
              f"conditions, which must be 0); not solvable: {s['targets'] - s['within_caps']} fail the necessary "
              f"conditions, {len(s['open'])} open (within them, solved by none){': ' + '; '.join(s['open']) if s['open'] else ''}")
        print(f"  TARGET detour solved {f['solved_solvable']}/{s['solvable']} solvable "
              f"({100 * f['solved_fraction_solvable']:.0f} %; target 100 %: "
              f"{'met' if f['solved_solvable'] == s['solvable'] else 'MISSED'}); planning time over them: median "
              f"{f['time_ms_median_solvable']:.1f} ms (target <= 5 ms: {'met' if f['time_ms_median_solvable'] <= 5 else 'MISSED'}), "
              f"p95 {f['time_ms_p95_solvable']:.1f} ms (target <= 50 ms: {'met' if f['time_ms_p95_solvable'] <= 50 else 'MISSED'}), "
              f"max {f['time_ms_max_solvable']:.1f} ms")

    for name, s in r["scenes"].items():
        block(f"scene '{name}'", s)
    block("scene set, all scenes", r["scene_set"])
    block("near-obstacle set (bin-sized box, targets 2-10 cm outside its faces)", r["near_obstacle"])
    target(r["near_obstacle"])
    caps = ", ".join(f"{k} {v:g}" for k, v in r["raised_caps"].items())
    block(f"scene set, per-plan caps raised ({caps})", r["scene_set_raised_caps"])
    block(f"near-obstacle set, per-plan caps raised ({caps})", r["near_obstacle_raised_caps"])
    block(f"near-obstacle set, per-plan caps raised and motion.sweep_resolution_m {r['finer_sweep_resolution_m']:g} m "
          "(the bundled policy's: 0.01 m)", r["near_obstacle_raised_caps_finer"])
