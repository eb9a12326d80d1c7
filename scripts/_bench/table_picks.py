#!/usr/bin/env python3
"""Table picks (issue 25): top-down picks on a grid of the table, through the Guard, densely checked.

The grid: TCP targets x 0.30–0.65 m step 0.05, y −0.30…0.30 m step 0.10 (56 cells) in the base
frame `fr3_link0` (the table is z = 0), hand down (quaternion x=1, y=0, z=0, w=0). Each cell, from
home, as a client does it through the MCP tools (the real server and Guard of
`tests.server.harness`, the bundled policy with its rate limits raised — the grid calls far faster
than an agent would):

1. `plan_to_pose` to the pre-grasp 12 cm above (z = 0.14 m) with `free_yaw` (the hand down, any turn
   about the tool axis, as the denominator allows; `--fixed-yaw` asks for the quaternion exactly),
   executed; where one plan is refused, two: via the point halfway along the TCP's straight line
   from home (the per-plan caps limit one plan's TCP path and joint travel);
2. `plan_cartesian_path` straight down to z = 0.02 m, executed; 3. straight back up to 0.14 m,
   executed;
4. back home by `plan_to_joints` (retracing the approach where one plan cannot), executed — not
   part of the pick, but an executed path all the same.

Every plan asks for the policy's largest velocity and acceleration scaling (it only shortens the
run). A cell is *picked* when steps 1–3 all executed; every trajectory the backend was sent
(recorded where the Guard hands it to the backend) is checked afterwards by `dense_check`.

The denominator — the cells a real FR3 reaches hand-down within its joint limits — comes from
`reachable_cells` (IK from many seeds, hand down with any yaw about the vertical, Franka's
collision meshes clear of the table, of themselves and of the policy's zones), written to
`tests/planning/data/table_reachable.yaml` by

    .venv/bin/python scripts/_bench/table_picks.py reachable

(needs the local mesh cache: `scripts/_bench/dense_check.py --source PATH`). `run` runs the grid
on one backend and prints what `bench.py table` reports.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import statistics
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import yaml

ROOT = Path(__file__).resolve().parents[2]
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
for _path in (ROOT / "src", ROOT):  # after PYTHONPATH: a copy of the sources named there wins
    if str(_path) not in sys.path:
        sys.path.append(str(_path))

import dense_check  # noqa: E402 - scripts/_bench on the path above
from dense_check import ArmKinematics, DenseChecker, Meshes, PathReport, Zone  # noqa: E402

#: grid of the issue [m]
GRID_X = tuple(round(0.30 + 0.05 * i, 2) for i in range(8))
GRID_Y = tuple(round(-0.30 + 0.10 * j, 2) for j in range(7))
GRASP_Z_M = 0.02
PREGRASP_Z_M = 0.14
#: hand down: the quaternion (x, y, z, w) of the issue, and its rotation matrix
DOWN_XYZW = (1.0, 0.0, 0.0, 0.0)
DOWN = np.diag([1.0, -1.0, -1.0])
DOWN_ARG = {"x": 1.0, "y": 0.0, "z": 0.0, "w": 0.0}
#: the gripper's opening throughout (the backends start open; no grasp is made)
GRIPPER_WIDTH_M = 0.08
SCALING = {"velocity_scaling": 0.3, "acceleration_scaling": 0.3}
RAISED_RATE_LIMITS = {
    f"rate_limits.{key}": 100000
    for key in ("global_per_minute", "default_per_minute", "per_tool.plan_to_pose", "per_tool.plan_to_joints",
                "per_tool.plan_cartesian_path", "per_tool.execute_plan")
}
REACHABLE = ROOT / "tests" / "planning" / "data" / "table_reachable.yaml"
REACHABLE_FORMAT = "armwarden-table-reachable/1"
REGENERATE = ".venv/bin/python scripts/_bench/table_picks.py reachable"
#: a fixed subset of the grid for a backend too slow for all 56 in CI: a near corner, the centre, an
#: inner cell and a far corner (two approach plans)
SUBSET = ((0.30, -0.30), (0.45, 0.0), (0.55, 0.10), (0.65, 0.30))


def grid_cells() -> list[tuple[float, float]]:
    """The 56 cells, x-major."""
    return [(x, y) for x in GRID_X for y in GRID_Y]


def cell_name(cell: tuple[float, float]) -> str:
    return f"({cell[0]:.2f}, {cell[1]:+.2f})"


# =========================================================================== the denominator


@dataclass(frozen=True)
class SearchOptions:
    """How hard `reachable_cells` looks for a hand-down solution of one cell."""

    seeds: int = 600  # random seeds per cell (uniform within the limits), after home
    rng_seed: int = 2025
    iterations: int = 300
    position_tolerance_m: float = 1e-5
    axis_tolerance_rad: float = 1e-4  # angle between the tool axis and straight down
    damping: float = 1e-4


class HandDownIk:
    """Hand-down IK with the yaw free: the TCP at a point, its z axis straight down.

    Five constraints on seven joints: the residual is the position error and the tool axis's
    error (R·ez − (−ez)); damped least squares, every step clipped to the joint limits. Its own
    solver, not the planner's: the denominator must not inherit the planner's blind spots."""

    def __init__(self, arm: ArmKinematics, options: SearchOptions) -> None:
        self.arm, self.options = arm, options
        self.tcp = arm.model.getFrameId("fr3_hand_tcp")

    def solve(self, target: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
        model, data, opts = self.arm.model, self.arm.data, self.options
        q = np.clip(seed, self.arm.lower, self.arm.upper)
        down = np.array([0.0, 0.0, -1.0])
        for _ in range(opts.iterations):
            pin.computeJointJacobians(model, data, q)
            placement = pin.updateFramePlacement(model, data, self.tcp)
            axis = placement.rotation[:, 2]
            error = np.concatenate([target - placement.translation, down - axis])
            if (np.linalg.norm(error[:3]) < opts.position_tolerance_m
                    and math.acos(min(1.0, float(axis @ down))) < opts.axis_tolerance_rad):
                return q
            jac = pin.getFrameJacobian(model, data, self.tcp, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            # d(axis)/dq = ω × axis = −[axis]× J_ω
            skew = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
            full = np.vstack([jac[:3], -skew @ jac[3:]])
            step = full.T @ np.linalg.solve(full @ full.T + opts.damping * np.eye(6), error)
            largest = float(np.abs(step).max())
            if largest > 0.5:
                step *= 0.5 / largest
            q = np.clip(q + step, self.arm.lower, self.arm.upper)
        return None


class MeshCollision:
    """Franka's collision meshes at one configuration: against the table, the zones, each other.

    Self-collision pairs: links with at least two moving joints between them (as
    `scripts/fit_geometry.py --evaluate` counts them); links one joint apart touch by construction."""

    def __init__(self, arm: ArmKinematics, meshes: Meshes, zones: Sequence[Zone]) -> None:
        self.arm = arm
        self.geometry = dense_check.mesh_bodies(arm, meshes)
        self.table = DenseChecker(arm, self.geometry, zones)
        full = arm.full

        def moving_joints(link: str) -> set[int]:
            joint, chain = int(full.frames[full.getFrameId(link, pin.FrameType.BODY)].parentJoint), set()
            while joint != 0:
                chain.add(joint)
                joint = int(full.parents[joint])
            return chain

        bodies = self.geometry.bodies
        self.pairs = [(a, b) for a in range(len(bodies)) for b in range(a + 1, len(bodies))
                      if len(moving_joints(bodies[a].link) ^ moving_joints(bodies[b].link)) >= 2]

    def clearances(self, q: np.ndarray) -> dict[str, float]:
        """{"table", "zones", "self"} [m]: the smallest gap (≤ 0 in contact); zones and table as
        `DenseChecker` measures them, self-collision by coal's exact mesh distance."""
        report = self.table.check_configuration(q)
        frames = self.arm.joint_frames(np.asarray(q, dtype=float)[None])[0]
        placed = []
        for body in self.geometry.bodies:
            placement = frames[body.joint] if body.joint >= 0 else np.eye(4)
            placed.append(coal.Transform3s(placement[:3, :3], placement[:3, 3]) * body.local)
        closest = math.inf
        for a, b in self.pairs:
            shape_a, shape_b = self.geometry.bodies[a].shape, self.geometry.bodies[b].shape
            if coal.collide(shape_a, placed[a], shape_b, placed[b], coal.CollisionRequest(), coal.CollisionResult()):
                closest = min(closest, 0.0)
                continue
            closest = min(closest, float(coal.distance(shape_a, placed[a], shape_b, placed[b],
                                                       coal.DistanceRequest(), coal.DistanceResult())))
        return {"table": report.table_clearance_m, "zones": min(report.zone_clearance_m.values(), default=math.inf),
                "self": closest}


@dataclass(frozen=True)
class Reachability:
    """One cell of the denominator: a witness configuration, or how hard the search looked."""

    x: float
    y: float
    reachable: bool
    q: tuple[float, ...] = ()
    yaw_rad: float = 0.0
    clearance_m: dict[str, float] = field(default_factory=dict)
    solutions: int = 0  # IK solutions found (hand down, within the limits) up to the witness, or in all
    seeds: int = 0  # seeds tried up to the witness, or in all


def reachable_cells(meshes: Meshes, zones: Sequence[Zone], options: SearchOptions | None = None,
                    cells: Sequence[tuple[float, float]] | None = None,
                    home: Sequence[float] | None = None) -> list[Reachability]:
    """For each cell, the first hand-down IK solution (home first, then random seeds) whose meshes
    are clear of the table, the zones and each other; or none from all the seeds."""
    options = options or SearchOptions()
    arm = ArmKinematics(GRIPPER_WIDTH_M)
    ik = HandDownIk(arm, options)
    collision = MeshCollision(arm, meshes, zones)
    rng = np.random.default_rng(options.rng_seed)
    seeds = [np.asarray(home if home is not None else HOME, dtype=float)]
    seeds += [rng.uniform(arm.lower, arm.upper) for _ in range(options.seeds)]
    out = []
    for x, y in cells or grid_cells():
        target = np.array([x, y, GRASP_Z_M])
        found, tried, witness = 0, 0, None
        for seed in seeds:
            tried += 1
            q = ik.solve(target, seed)
            if q is None:
                continue
            found += 1
            gaps = collision.clearances(q)
            if min(gaps.values()) > 0.0:
                witness = (q, gaps)
                break
        if witness is None:
            out.append(Reachability(x, y, False, solutions=found, seeds=tried))
            continue
        q, gaps = witness
        rotation = arm.tcp_pose(q).rotation
        yaw = math.atan2(rotation[1, 0], rotation[0, 0])
        out.append(Reachability(x, y, True, tuple(float(v) for v in q), yaw, gaps, found, tried))
    return out


HOME = (0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398)


def write_reachable(results: Sequence[Reachability], meshes: Meshes, zones: Sequence[Zone],
                    options: SearchOptions, out: Path = REACHABLE) -> None:
    reachable = sum(r.reachable for r in results)
    lines = [
        "# Which cells of the table-pick grid a real FR3 reaches hand-down within its joint limits (issue 25).",
        f"# GENERATED by `{REGENERATE}` (scripts/_bench/table_picks.py); do not edit by hand.",
        "#",
        "# A cell is reachable when some IK solution (the TCP at (x, y, grasp_z_m), its z axis straight down, any yaw",
        "# about the vertical), within the joint limits, has Franka's collision meshes clear of the table (z > 0; link0 is",
        "# bolted to it), of each other (links with at least two moving joints between them) and of the bundled policy's",
        "# keep-out zones, the fingers open gripper_width_m. Search: the home pose, then `seeds` random seeds, for each a",
        "# damped least-squares solve (scripts/_bench/table_picks.py HandDownIk); the first clear solution is the",
        "# witness `q` [rad] (clearances [m]: zones exact within 0.05 m, beyond that a lower bound; `seeds`: seeds tried",
        "# until then, `solutions`: hand-down solutions found); an unreachable cell found no clear solution from any",
        "# seed (`solutions`: how many it found, all in contact).",
        f"# Our own computation from the meshes of franka_description at {meshes.commit}",
        "# (Apache-2.0, Copyright 2023 Franka Robotics GmbH); the meshes themselves are not committed.",
        f"# Reachable: {reachable} of {len(results)} cells.",
        f"format: {REACHABLE_FORMAT}",
        f"grasp_z_m: {GRASP_Z_M}",
        f"orientation_xyzw: {list(DOWN_XYZW)}",
        f"gripper_width_m: {GRIPPER_WIDTH_M}",
        f"meshes_commit: \"{meshes.commit}\"",
        f"zones: [{', '.join(z.name for z in zones)}]",
        f"search: {{seeds: {options.seeds}, rng_seed: {options.rng_seed}, iterations: {options.iterations}, "
        f"position_tolerance_m: {options.position_tolerance_m}, axis_tolerance_rad: {options.axis_tolerance_rad}}}",
        f"reachable: {reachable}",
        "cells:",
    ]
    for r in results:
        head = f"  - {{x: {r.x}, y: {r.y}, reachable: {str(r.reachable).lower()}, solutions: {r.solutions}, seeds: {r.seeds}"
        if r.reachable:
            q = ", ".join(f"{v:.6f}" for v in r.q)
            gaps = ", ".join(f"{k}: {v:.4f}" for k, v in r.clearance_m.items())
            head += f", yaw_rad: {r.yaw_rad:.4f}, q: [{q}], clearance_m: {{{gaps}}}"
        lines.append(head + "}")
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")


def load_reachable(path: Path = REACHABLE) -> dict[str, Any]:
    document = yaml.safe_load(path.read_text(encoding="utf-8"))
    if document.get("format") != REACHABLE_FORMAT:
        raise ValueError(f"{path}: not a {REACHABLE_FORMAT} file")
    return document


def reachable_set(document: dict[str, Any]) -> set[tuple[float, float]]:
    return {(round(c["x"], 2), round(c["y"], 2)) for c in document["cells"] if c["reachable"]}


# =========================================================================== the grid through the Guard


@dataclass
class Step:
    """One tool call of a cell and what came of it."""

    tool: str
    status: str  # ok | needs_approval | rejected | error | succeeded | aborted
    seconds: float
    codes: tuple[str, ...] = ()
    detail: str = ""


@dataclass
class CellRun:
    """One cell on one backend."""

    x: float
    y: float
    picked: bool = False
    approach_plans: int = 0  # 1, or 2 where one plan was refused
    approvals: int = 0
    steps: list[Step] = field(default_factory=list)
    failure: str = ""
    home: bool = False  # back home afterwards
    #: every trajectory the backend was sent during this cell (approach, descent, lift, return)
    sent: list[np.ndarray] = field(default_factory=list)

    @property
    def cell(self) -> tuple[float, float]:
        return (self.x, self.y)

    def plan_seconds(self, tools: Sequence[str]) -> list[float]:
        return [s.seconds for s in self.steps if s.tool in tools and s.status in ("ok", "needs_approval", "rejected")]


def _text(result: Any) -> str:
    return " ".join(getattr(block, "text", "") for block in result.content)


def record_sent(backend: Any) -> list[Any]:
    """Every trajectory `backend.execute` receives, in order (the Guard's CountingBackend forwards
    the very object it was handed, so this is what the backend ran)."""
    sent: list[Any] = []
    original = backend.execute

    async def execute(trajectory: Any, progress: Any = None, *, stop_epoch: int | None = None) -> Any:
        sent.append(trajectory)
        return await original(trajectory, progress, stop_epoch=stop_epoch)

    backend.execute = execute
    return sent


class GridRunner:
    """Runs cells through one SDK client of the harness; `sent` is the backend's recorder."""

    def __init__(self, client: Any, sent: list[Any], prompts: list[str], backend: Any = None, *,
                 free_yaw: bool = True) -> None:
        self.client, self.sent, self.prompts, self.backend = client, sent, prompts, backend
        #: the pose requests allow any turn about the tool axis (the denominator does too)
        self.pose = {"orientation": DOWN_ARG, "free_yaw": True} if free_yaw else {"orientation": DOWN_ARG}

    async def _plan(self, run: CellRun, tool: str, arguments: dict[str, Any]) -> str | None:
        """A plan id if the plan may be executed (ok, or needs approval); the step is noted."""
        start = time.perf_counter()
        result = await self.client.call_tool(tool, {**arguments, **SCALING, "preview": False})
        seconds = time.perf_counter() - start
        if result.is_error:
            run.steps.append(Step(tool, "error", seconds, detail=_text(result)[:400]))
            return None
        summary = result.structured_content
        codes = tuple(v["code"] for v in summary["violations"])
        detail = "; ".join(v["detail"] for v in summary["violations"])[:600]
        run.steps.append(Step(tool, summary["status"], seconds, codes, detail))
        return summary["plan_id"] if summary["status"] in ("ok", "needs_approval") else None

    async def _execute(self, run: CellRun, plan_id: str) -> bool:
        asked, before = len(self.prompts), len(self.sent)
        start = time.perf_counter()
        result = await self.client.call_tool("execute_plan", {"plan_id": plan_id})
        seconds = time.perf_counter() - start
        run.approvals += len(self.prompts) - asked
        run.sent += [np.array(t.positions) for t in self.sent[before:]]
        if result.is_error:
            run.steps.append(Step("execute_plan", "error", seconds, detail=_text(result)[:400]))
            return False
        status = result.structured_content["status"]
        run.steps.append(Step("execute_plan", status, seconds, detail=result.structured_content.get("detail", "")[:200]))
        return status == "succeeded"

    async def _move(self, run: CellRun, tool: str, arguments: dict[str, Any]) -> bool:
        plan_id = await self._plan(run, tool, arguments)
        return plan_id is not None and await self._execute(run, plan_id)

    async def joints(self) -> np.ndarray:
        state = (await self.client.call_tool("get_robot_state", {})).structured_content
        return np.array(state["joint_positions"])

    async def tcp(self) -> np.ndarray:
        p = (await self.client.call_tool("get_robot_state", {})).structured_content["tcp_pose"]["position"]
        return np.array([p["x"], p["y"], p["z"]])

    async def pick(self, cell: tuple[float, float], home: Sequence[float]) -> CellRun:
        """One cell from home: approach (one plan, else two), descend, lift, then back home."""
        x, y = cell
        run = CellRun(x, y)
        approach: list[np.ndarray] = []  # the paths the approach executed (to retrace on the way home)
        pre = {"x": x, "y": y, "z": PREGRASP_Z_M}
        approached = False
        if await self._move(run, "plan_to_pose", {"position": pre, **self.pose}):
            run.approach_plans, approached = 1, True
            approach.append(run.sent[-1])
        elif run.steps[-1].tool != "execute_plan":  # refused (not failed while moving): two plans
            here = await self.tcp()
            mid = (here + np.array([x, y, PREGRASP_Z_M])) / 2.0
            middle = {"x": float(mid[0]), "y": float(mid[1]), "z": float(mid[2])}
            if await self._move(run, "plan_to_pose", {"position": middle, **self.pose}):
                approach.append(run.sent[-1])
                if await self._move(run, "plan_to_pose", {"position": pre, **self.pose}):
                    run.approach_plans, approached = 2, True
                    approach.append(run.sent[-1])
        if approached:
            down = await self._move(run, "plan_cartesian_path", {"waypoints": [{"position": {**pre, "z": GRASP_Z_M}}]})
            up = down and await self._move(run, "plan_cartesian_path", {"waypoints": [{"position": pre}]})
            run.picked = bool(down and up)
        if not run.picked:
            failed = next((s for s in reversed(run.steps) if s.status not in ("ok", "needs_approval", "succeeded")), None)
            run.failure = f"{failed.tool}: {failed.status} {','.join(failed.codes)} {failed.detail}" if failed else "?"
        run.home = await self.go_home(run, home, approach)
        return run

    async def go_home(self, run: CellRun, home: Sequence[float], approach: Sequence[np.ndarray]) -> bool:
        """Home in one plan, else back along the approach: to the middle and the start of each
        path it executed, last first (halves of paths the caps allowed)."""
        home_q = np.asarray(home, dtype=float)
        if float(np.max(np.abs(await self.joints() - home_q))) < 1e-3:
            return True
        if await self._move(run, "plan_to_joints", {"joint_positions": list(home_q)}):
            return True
        for path in reversed(approach):
            for q in (path[len(path) // 2], path[0]):
                if not await self._move(run, "plan_to_joints", {"joint_positions": [float(v) for v in q]}):
                    return False
        return float(np.max(np.abs(await self.joints() - home_q))) < 1e-2


@contextlib.asynccontextmanager
async def grid_harness(backend: str, tmp: Path, speedup: float | None = None, *,
                       free_yaw: bool = True) -> AsyncIterator[GridRunner]:
    """The daemon on `backend` (the bundled policy, rate limits raised) behind one SDK client."""
    from tests.server.harness import approve, arm_harness, policy_with

    policy = policy_with(**RAISED_RATE_LIMITS)
    options: dict[str, Any] = {} if speedup is None else {"speedup": speedup}
    operator = approve("table-picks")
    async with arm_harness(tmp, policy, backend=backend, **options) as arm:
        sent = record_sent(arm.inner)
        async with arm.client(elicitation=operator) as client:
            yield GridRunner(client, sent, operator.prompts, arm.inner, free_yaw=free_yaw)  # type: ignore[attr-defined]


async def run_grid(backend: str, cells: Sequence[tuple[float, float]], tmp: Path, speedup: float | None = None,
                   progress: Callable[[CellRun], None] | None = None, stats: dict[str, Any] | None = None,
                   free_yaw: bool = True) -> list[CellRun]:
    """Every cell in order on one daemon; a cell that cannot get back home ends that daemon and
    the next cell starts on a fresh one (so every cell starts from home). `stats` gets the number
    of daemons started and the physics steps a simulation dropped (it fell behind its speedup)."""
    from tests.helpers import HOME

    runs: list[CellRun] = []
    remaining = list(cells)
    attempt = 0
    while remaining:
        attempt += 1
        (tmp / f"daemon{attempt}").mkdir(parents=True, exist_ok=True)
        async with grid_harness(backend, tmp / f"daemon{attempt}", speedup, free_yaw=free_yaw) as runner:
            while remaining:
                run = await runner.pick(remaining.pop(0), HOME)
                runs.append(run)
                if progress is not None:
                    progress(run)
                if not run.home:
                    break
            if stats is not None:
                stats["daemons"] = attempt
                physics = getattr(runner.backend, "arm", None)  # the MuJoCo backend's SimulatedArm
                stats["dropped_steps"] = stats.get("dropped_steps", 0) + int(getattr(physics, "dropped_steps", 0))
    return runs


def dense_reports(runs: Sequence[CellRun], zones: Sequence[Zone], meshes: Meshes | None) -> list[PathReport]:
    """Every sent trajectory against the fitted capsules, and the meshes when there are any."""
    arm = ArmKinematics(GRIPPER_WIDTH_M)
    geometries = [dense_check.fitted_capsules(arm)]
    if meshes is not None:
        geometries.append(dense_check.mesh_bodies(arm, meshes))
    reports = []
    for geometry in geometries:
        checker = DenseChecker(arm, geometry, zones)
        reports.append(dense_check.merged((checker.check(p) for run in runs for p in run.sent), geometry.kind))
    return reports


# =========================================================================== the benchmark


def summarise(runs: Sequence[CellRun], reachable: set[tuple[float, float]]) -> dict[str, Any]:
    picked = {r.cell for r in runs if r.picked}
    among = picked & reachable
    pose_s = [s for r in runs for s in r.plan_seconds(("plan_to_pose",))]
    cart_s = [s for r in runs for s in r.plan_seconds(("plan_cartesian_path",))]

    def times(values: list[float]) -> dict[str, float]:
        if not values:
            return {"n": 0, "median_ms": math.nan, "p95_ms": math.nan}
        return {"n": len(values), "median_ms": statistics.median(values) * 1e3,
                "p95_ms": float(np.percentile(np.asarray(values), 95)) * 1e3}

    return {
        "cells": len(runs),
        "reachable": len(reachable & {r.cell for r in runs}),
        "picked": len(picked),
        "picked_of_reachable": len(among),
        "fraction": len(among) / max(1, len(reachable & {r.cell for r in runs})),
        "two_plan_approaches": sum(r.approach_plans == 2 for r in runs),
        "approvals": sum(r.approvals for r in runs),
        "not_home": sum(not r.home for r in runs),
        "plan_to_pose": times(pose_s),
        "plan_cartesian_path": times(cart_s),
        "failures": {cell_name(r.cell): r.failure for r in runs if not r.picked},
        "picked_unreachable": sorted(cell_name(c) for c in picked - reachable),
    }


def bench_table(backends: Sequence[str] = ("fake", "mujoco"), speedups: dict[str, float] | None = None,
                free_yaw: bool = True) -> dict[str, Any]:
    """The whole grid on each backend, and the dense check of every path sent."""
    from armwarden.policy import bundled_policy, load_policy

    speedups = {"fake": 1000.0, "mujoco": 4.0} | (speedups or {})  # MuJoCo faster drops physics steps here
    zones = dense_check.policy_zones(load_policy(bundled_policy("fr3")))
    meshes = dense_check.load_meshes()
    document = load_reachable()
    reachable = reachable_set(document)
    out: dict[str, Any] = {"denominator": {"reachable": len(reachable), "cells": len(document["cells"]),
                                           "meshes_commit": document["meshes_commit"], "free_yaw": free_yaw}}
    for backend in backends:
        with tempfile.TemporaryDirectory() as tmp:
            start, stats = time.perf_counter(), {}
            runs = asyncio.run(run_grid(backend, grid_cells(), Path(tmp), speedups.get(backend), stats=stats,
                                        free_yaw=free_yaw))
            wall = time.perf_counter() - start
        result = summarise(runs, reachable)
        result["wall_s"] = wall
        result.update(stats)
        result["speedup"] = speedups.get(backend)
        result["dense"] = [{"geometry": r.geometry, "paths": r.paths, "samples": r.samples, "clear": r.clear,
                            "contacts": r.contact_count, "first_contacts": r.contacts[:5],
                            "table_clearance_m": r.table_clearance_m, "table_body": r.table_body,
                            "zone_clearance_m": r.zone_clearance_m} for r in dense_reports(runs, zones, meshes)]
        if meshes is None:
            result["dense"].append({"geometry": "meshes", "skipped": f"no mesh cache at {dense_check.mesh_cache_path()}"})
        out[backend] = result
    return out


def report_table(r: dict[str, Any]) -> None:
    d = r["denominator"]
    print(f"table picks: {d['reachable']} of {d['cells']} cells reachable hand-down by a real FR3 "
          f"(IK + Franka's meshes at {d['meshes_commit'][:7]}; tests/planning/data/table_reachable.yaml); pose requests "
          f"{'with free_yaw' if d['free_yaw'] else 'at the exact hand-down quaternion'}")
    for backend, b in r.items():
        if backend == "denominator":
            continue
        goal = "met" if b["fraction"] >= 0.95 else "MISSED"
        print(f"  {backend} (speedup {b['speedup']:g}, {b['wall_s']:.0f} s): picked {b['picked_of_reachable']}/"
              f"{b['reachable']} reachable = {b['fraction'] * 100:.1f} % (goal >= 95 %: {goal}); all picked "
              f"{b['picked']}/{b['cells']}; two-plan approaches {b['two_plan_approaches']}, approvals asked "
              f"{b['approvals']}, cells not back home {b['not_home']}, physics steps dropped {b.get('dropped_steps', 0)}")
        for tool in ("plan_to_pose", "plan_cartesian_path"):
            t = b[tool]
            print(f"    {tool}: median {t['median_ms']:.1f} ms, p95 {t['p95_ms']:.1f} ms over {t['n']} calls (round trip)")
        for dense in b["dense"]:
            if "skipped" in dense:
                print(f"    dense check, {dense['geometry']}: skipped ({dense['skipped']})")
                continue
            zones = ", ".join(f"{k} {v * 1e3:.0f} mm" for k, v in sorted(dense["zone_clearance_m"].items()))
            verdict = "clear" if dense["clear"] else f"{dense['contacts']} CONTACTS, e.g. {dense['first_contacts'][:2]}"
            print(f"    dense check, {dense['geometry']}: {dense['paths']} paths, {dense['samples']} configurations "
                  f"(<= 1 mm apart): {verdict}; lowest {dense['table_clearance_m'] * 1e3:.1f} mm above the table "
                  f"({dense['table_body']}); nearest zones {zones}")
        for cell, why in list(b["failures"].items())[:60]:
            print(f"    not picked {cell}: {why[:300]}")
        if b["picked_unreachable"]:
            print(f"    picked though not in the denominator: {', '.join(b['picked_unreachable'])}")


# =========================================================================== command line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    reach = sub.add_parser("reachable", help=f"compute the denominator, write {REACHABLE.relative_to(ROOT)}")
    reach.add_argument("--meshes", type=Path, default=None, help="mesh cache (default: dense_check's)")
    reach.add_argument("--seeds", type=int, default=SearchOptions.seeds)
    reach.add_argument("--out", type=Path, default=REACHABLE)
    run = sub.add_parser("run", help="run the grid and report as `bench.py table` does")
    run.add_argument("--backend", action="append", choices=("fake", "mujoco"), default=None)
    run.add_argument("--speedup", type=float, default=None)
    run.add_argument("--fixed-yaw", action="store_true", help="ask for the hand-down quaternion exactly (no free_yaw)")
    args = parser.parse_args(argv)
    if args.command == "reachable":
        from armwarden.policy import bundled_policy, load_policy

        meshes = dense_check.load_meshes(args.meshes)
        if meshes is None:
            parser.error(f"no mesh cache at {args.meshes or dense_check.mesh_cache_path()}: make it with "
                         "scripts/_bench/dense_check.py --source PATH")
        zones = dense_check.policy_zones(load_policy(bundled_policy("fr3")))
        options = SearchOptions(seeds=args.seeds)
        start = time.perf_counter()
        results = reachable_cells(meshes, zones, options)
        write_reachable(results, meshes, zones, options, args.out)
        print(f"{sum(r.reachable for r in results)} of {len(results)} cells reachable "
              f"({time.perf_counter() - start:.0f} s); wrote {args.out}", file=sys.stderr)
        return 0
    backends = tuple(args.backend or ("fake", "mujoco"))
    speedups: dict[str, float] | None = {b: float(args.speedup) for b in backends} if args.speedup else None
    report_table(bench_table(backends, speedups, free_yaw=not args.fixed_yaw))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
