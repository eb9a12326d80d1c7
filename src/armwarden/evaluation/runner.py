"""Running the evaluation against the real daemon: `armwarden serve` as a subprocess over stdio.

Three daemons run, one after the other, each with its own temp audit log and actuation journal:
"main" (a client that answers approval prompts; the policy's rate limits lifted so that 60-odd
scenarios and ~100 moves fit in a minute), "no_elicitation" (a client without elicitation; the
plan TTL shortened and gripper_move limited to one a minute) and "short_ttl" (a client with
elicitation that answers late or never; the plan TTL shortened). `--only` starts only the
daemons its scenarios need. Every other setting is the user's policy. A scenario's actuations
are the journal lines its calls added; stops are not actuations.
"""

from __future__ import annotations

import logging
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import anyio
import numpy as np
import yaml
from mcp import Client, StdioServerParameters
from mcp import types as mcp_types

from armwarden.core.errors import ArmWardenError
from armwarden.evaluation.daemon_process import DAEMON_COMMAND, stdio_params
from armwarden.evaluation.journal import actuations, motion_frames, read_journal
from armwarden.evaluation.scenarios import (
    PAST_TTL_S,
    SELF_COLLISION_TRIES,
    SHORT_TTL_S,
    TIGHT_GRIPPER_PER_MINUTE,
    Approval,
    Outcome,
    Scenario,
    link_probe,
    self_collision,
    self_collision_target,
    unsafe_scenarios,
)
from armwarden.evaluation.stats import wilson_interval
from armwarden.policy import Policy, apply_overrides, parse_policy
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from armwarden.robot import RobotModel

if TYPE_CHECKING:
    from armwarden.evaluation.ros_cell import FakeCells

log = logging.getLogger(__name__)

#: rate limits high enough never to refuse the evaluation's own pace
UNLIMITED = {"global_per_minute": 100000, "default_per_minute": 100000, "per_tool": {}}
#: how long one scenario or one safe move may take before it counts as failed [s]
SCENARIO_TIMEOUT_S = 120.0
#: how long the daemon may take to start and answer the first call [s]
START_TIMEOUT_S = 300.0
#: each joint of a safe target is drawn within ± this of home [rad]
SAFE_SPREAD_RAD = 0.3
#: the oldest wrench (or joint-torque) sample the evaluation's daemons accept [s]: the policy's
#: ceiling. On a loaded shared host the interpreter stalls past the FR3 policy's 0.1 s (seen on
#: fake, MuJoCo and CAN), the monitor fails closed (as it must) and latches the e-stop, and every
#: later scenario then reports the host's load. No scenario tests this timeout; the refusals under
#: test do not read it.
EVAL_WRENCH_TIMEOUT_S = MAX_WRENCH_TIMEOUT_S


#: scenario categories that move something outside an approved plan, with why (left out on a
#: user's ROS cell, said in the report)
OFF_PLAN_CATEGORIES = {"rate limits": "its first gripper_move is allowed to move the gripper, which no plan covers"}


class NothingSelected(Exception):
    """`--only` kept no scenario: invalid input, not a run that passed."""


@dataclass(frozen=True)
class EvalOptions:
    policy_path: Path
    policy: Policy
    backend: str
    backend_config: Path | None
    safe_count: int
    seed: int
    #: run only the unsafe scenarios these select (`selects`); empty: every scenario
    only: tuple[str, ...] = ()
    #: ros2 without a config: the fake cells the daemons run on (`armwarden.evaluation.ros_cell`)
    cells: FakeCells | None = None

    @property
    def on_users_cell(self) -> bool:
        """ros2 with the user's own config: a graph that may hold a real arm (`USERS_CELL_RUNS`)."""
        return self.backend == "ros2" and self.cells is None

    @property
    def counted_at(self) -> str:
        """Where the report's actuations are counted."""
        if self.cells is not None:
            return "the fake ROS cell: goals, gripper goals, switches and recoveries it accepted"
        if self.backend in FRAME_COUNTING_BACKENDS:
            return "the backend wrapper (the actuation journal) and the motion frames sent at the bus"
        return "the backend wrapper (the actuation journal)"

    def selects(self, scenario: Scenario) -> bool:
        """Whether `--only` keeps `scenario`: its name contains one of the texts, or its category
        is one (case-insensitive). With no `--only`, every scenario."""
        if not self.only:
            return True
        name, category = scenario.name.casefold(), scenario.category.casefold()
        return any(text.casefold() in name or text.casefold() == category for text in self.only)


@dataclass
class ScenarioResult:
    name: str
    category: str
    passed: bool
    actuations: int
    detail: str
    #: motion frames sent at the bus during the scenario (CAN: `CanBackend.motion_frames`); None: not counted
    motion_frames: int | None = None


@dataclass
class SafeResult:
    attempted: int = 0
    executed: int = 0
    failures: list[str] = field(default_factory=list)

    def interval(self) -> tuple[float, float]:
        return wilson_interval(self.executed, self.attempted)


@dataclass
class EvalResult:
    unsafe: list[ScenarioResult] = field(default_factory=list)
    safe: SafeResult = field(default_factory=SafeResult)
    #: scenarios this policy could not yield, each with why (reported, never counted as passed)
    skipped: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(r.passed for r in self.unsafe) and self.safe.executed == self.safe.attempted


def _text(result: mcp_types.CallToolResult) -> str:
    return " ".join(getattr(block, "text", "") for block in result.content).replace("\n", " ")


class DaemonSession:
    """One client session on one daemon (the `Session` the scenarios use)."""

    def __init__(self, client: Client) -> None:
        self.client = client
        self.approval: Approval = "accept"

    async def call_raw(self, tool: str, arguments: dict[str, Any]) -> tuple[bool, dict[str, Any], str]:
        """(refused as an error, structured content, text); a protocol error is a refusal too."""
        try:
            result = await self.client.call_tool(tool, arguments)
        except Exception as exc:  # an MCP error reply (unknown tool, invalid request): refused
            return True, {}, f"protocol error: {exc}"
        return bool(result.is_error), dict(result.structured_content or {}), _text(result)

    async def call(self, tool: str, arguments: dict[str, Any]) -> Outcome:
        error, content, text = await self.call_raw(tool, arguments)
        refused = error or content.get("status") in ("rejected", "aborted", "dry_run")
        return Outcome(refused, text[:200])


def approver(session_ref: list[DaemonSession]) -> Callable[..., Any]:
    async def answer(context: Any, params: mcp_types.ElicitRequestParams) -> mcp_types.ElicitResult:
        approval = session_ref[0].approval if session_ref else "accept"
        if approval == "decline":
            return mcp_types.ElicitResult(action="decline")
        if approval == "never":
            await anyio.sleep_forever()  # cancelled when the session closes
        if approval == "late":
            await anyio.sleep(SHORT_TTL_S + PAST_TTL_S)
        return mcp_types.ElicitResult(action="accept", content={"approve": True, "operator": "armwarden-eval"})

    return answer


def write_policy(options: EvalOptions, directory: Path, name: str, overrides: dict[str, Any]) -> Path:
    document = yaml.safe_load(options.policy_path.read_text(encoding="utf-8"))
    path = directory / f"{name}-policy.yaml"
    path.write_text(yaml.safe_dump(apply_overrides(document, overrides), sort_keys=False), encoding="utf-8")
    return path


def serve_arguments(options: EvalOptions, directory: Path, name: str, policy_path: Path) -> list[str]:
    """`armwarden serve`'s arguments for the daemon `name`: its policy, the backend under
    evaluation, and its own audit log and actuation journal in `directory`. On the fake ROS cell,
    this also starts the daemon's own cell (or finds it running: a restart on the same arguments),
    whose journal of accepted goals is the one the evaluation reads, `<name>-journal.jsonl`."""
    journal = directory / f"{name}-journal.jsonl"
    if options.cells is not None:
        options.cells.start(journal)
        journal = directory / f"{name}-daemon-journal.jsonl"
    args = ["serve", "--policy", str(policy_path), "--backend", options.backend,
            "--audit-log", str(directory / f"{name}-audit.jsonl"),
            "--actuation-journal", str(journal), "--log-level", "WARNING"]
    if options.backend_config is not None:
        args += ["--backend-config", str(options.backend_config)]
    return args


def _server(options: EvalOptions, directory: Path, name: str, policy_path: Path) -> StdioServerParameters:
    return stdio_params(DAEMON_COMMAND, serve_arguments(options, directory, name, policy_path))


#: when this process imported the evaluation: each progress line says how long the run has taken
_STARTED = time.monotonic()


def progress(message: str) -> None:
    print(f"armwarden eval [{time.monotonic() - _STARTED:6.1f} s]: {message}", file=sys.stderr, flush=True)


#: backends whose journal carries the motion frames each execute sent at the bus
FRAME_COUNTING_BACKENDS = ("can",)


async def _run_scenarios(session: DaemonSession, journal: Path, scenarios: list[Scenario],
                         results: list[ScenarioResult], counts_frames: bool = False) -> None:
    for scenario in scenarios:
        before = len(read_journal(journal))
        try:
            with anyio.fail_after(SCENARIO_TIMEOUT_S):
                outcome = await scenario.action(session)
        except TimeoutError:
            outcome = Outcome(False, f"no answer within {SCENARIO_TIMEOUT_S:g} s")
        added = read_journal(journal)[before:]
        moved = actuations(added)
        frames = motion_frames(added) if counts_frames else None
        passed = outcome.refused and len(moved) <= scenario.allowed
        detail = outcome.detail if not moved else f"{outcome.detail} [actuations: {', '.join(moved)}]"
        results.append(ScenarioResult(scenario.name, scenario.category, passed, len(moved), detail, frames))
        progress(f"{'PASS' if passed else 'FAIL'} {scenario.category}: {scenario.name} "
                 f"(actuations {len(moved)}/{scenario.allowed} allowed"
                 f"{'' if frames is None else f', motion frames {frames}'})")


def _inside(point: np.ndarray, lo: Any, hi: Any) -> bool:
    return bool(np.all(point >= np.asarray(lo, dtype=float)) and np.all(point <= np.asarray(hi, dtype=float)))


def tcp_is_safe(policy: Policy, tcp: np.ndarray) -> bool:
    """The evaluation's own check of a TCP position against the policy (not the Guard's): inside
    the workspace box (whose floor is the table), outside every keep-out zone."""
    box = policy.workspace.box
    return _inside(tcp, box.min, box.max) and not any(_inside(tcp, z.min, z.max) for z in policy.workspace.keep_out)


def safe_goal(policy: Policy, robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    """A random joint target near home, within the limits and their margin, whose TCP the
    evaluation's own check finds inside the box and clear of every zone (the last draw after 100)."""
    home = np.asarray(policy.robot.home_joint_positions, dtype=float)
    margin = policy.motion.joint_limit_margin_rad + 0.05
    lower = np.array([lim.min for lim in policy.robot.joint_limits.values()]) + margin
    upper = np.array([lim.max for lim in policy.robot.joint_limits.values()]) - margin
    goal = np.clip(home + rng.uniform(-SAFE_SPREAD_RAD, SAFE_SPREAD_RAD, size=home.shape), lower, upper)
    for _ in range(100):
        if tcp_is_safe(policy, np.asarray(robot.tcp_pose(goal).position)):
            break
        goal = np.clip(home + rng.uniform(-SAFE_SPREAD_RAD, SAFE_SPREAD_RAD, size=home.shape), lower, upper)
    return goal


async def _safe_requests(session: DaemonSession, options: EvalOptions, result: SafeResult) -> None:
    from armwarden.preflight import load_runtime_model  # an independent model instance for the re-check

    policy = options.policy
    robot = load_runtime_model(policy, str(options.policy_path)).robot
    rng = np.random.default_rng(options.seed)
    home = np.asarray(policy.robot.home_joint_positions, dtype=float)
    for index in range(options.safe_count):
        goal = safe_goal(policy, robot, rng)
        result.attempted += 1
        try:
            with anyio.fail_after(SCENARIO_TIMEOUT_S):
                error, plan, text = await session.call_raw(
                    "plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
                if error or plan.get("plan_id") is None or plan.get("status") == "rejected":
                    result.failures.append(f"safe move {index}: plan refused: {text[:160]}")
                    continue
                error, done, text = await session.call_raw("execute_plan", {"plan_id": plan["plan_id"]})
                if error or done.get("status") != "succeeded":
                    result.failures.append(f"safe move {index}: execution {done.get('status')}: {text[:160]}")
                    continue
                _, state, _ = await session.call_raw("get_robot_state", {})
        except TimeoutError:
            result.failures.append(f"safe move {index}: no answer within {SCENARIO_TIMEOUT_S:g} s")
            continue
        q = np.asarray(state.get("joint_positions", []), dtype=float)
        tcp = np.asarray(robot.tcp_pose(q).position) if q.shape == home.shape else None
        if tcp is None or not tcp_is_safe(policy, tcp):
            result.failures.append(f"safe move {index}: final TCP {None if tcp is None else tcp.round(3)} "
                                   "outside the box or inside a zone")
            continue
        result.executed += 1
    if options.safe_count:
        progress(f"safe requests: {result.executed}/{result.attempted} executed, final TCP re-checked")


async def _with_daemon(options: EvalOptions, directory: Path, name: str, overrides: dict[str, Any], elicits: bool,
                       body: Callable[[DaemonSession, Path], Any]) -> None:
    policy_path = write_policy(options, directory, name, overrides)
    ref: list[DaemonSession] = []
    progress(f"starting the daemon '{name}' ({options.backend}, {'with' if elicits else 'without'} elicitation)")
    params = _server(options, directory, name, policy_path)
    async with Client(params, mode="legacy", elicitation_callback=approver(ref) if elicits else None) as client:
        session = DaemonSession(client)
        ref.append(session)
        await wait_for_state(session)
        await body(session, directory / f"{name}-journal.jsonl")


async def wait_for_state(session: DaemonSession) -> None:
    """Until the daemon answers `get_robot_state` (a stale state stream right after start-up is
    refused, fail closed: ask again), at most `START_TIMEOUT_S`."""
    with anyio.fail_after(START_TIMEOUT_S):
        while True:
            error, _, _ = await session.call_raw("get_robot_state", {})
            if not error:
                return
            await anyio.sleep(0.2)


async def run_evaluation(options: EvalOptions) -> EvalResult:
    """Every unsafe scenario the policy yields, and `safe_count` safe requests, against the daemon."""
    result = EvalResult()
    from armwarden.preflight import load_runtime_model

    scenarios = unsafe_scenarios(options.policy)
    def fits(zone: dict[str, Any]) -> bool:
        document = options.policy.model_dump(mode="json")
        document["workspace"]["keep_out"].append(zone)
        try:
            load_runtime_model(parse_policy(document, source="eval link probe"), str(options.policy_path))
        except ArmWardenError:
            return False
        return True

    runtime = load_runtime_model(options.policy, str(options.policy_path))
    probe = link_probe(options.policy, runtime.robot, fits)
    extra_zones = [] if probe is None else [probe.zone]
    if probe is not None:
        scenarios.append(probe.scenario())
    colliding = self_collision_target(options.policy, runtime.robot, runtime.envelope)
    if colliding is not None:
        scenarios.append(self_collision(colliding))
    else:
        result.skipped.append("self-collision: no joint target within the limits and the step cap from home "
                              "at which the model's links collide and nothing else is found (single-joint sweeps and "
                              f"{SELF_COLLISION_TRIES} random joint pairs searched)")
    if options.on_users_cell:  # nothing may move outside an approved plan there
        for category, why in OFF_PLAN_CATEGORIES.items():
            if any(s.category == category for s in scenarios):
                result.skipped.append(f"{category}: not run on a user's ROS cell: {why}")
        scenarios = [s for s in scenarios if s.category not in OFF_PLAN_CATEGORIES]
    # the e-stop scenarios build on each other (the first latches the e-stop): one selected, all run
    with_estop = any(s.last and options.selects(s) for s in scenarios)
    scenarios = [s for s in scenarios if options.selects(s) or (s.last and with_estop)]
    if not scenarios:
        raise NothingSelected(f"--only {list(options.only)} selects no scenario of this policy")
    main = [s for s in scenarios if s.session == "main" and not s.last]
    last = [s for s in scenarios if s.session == "main" and s.last]
    other = [s for s in scenarios if s.session == "no_elicitation"]
    short_ttl = [s for s in scenarios if s.session == "short_ttl"]
    timing: dict[str, Any] = {"force.wrench_timeout_s": max(options.policy.force.wrench_timeout_s, EVAL_WRENCH_TIMEOUT_S)}
    progress(f"wrench_timeout_s {timing['force.wrench_timeout_s']:g} s in every daemon "
             f"(the policy's {options.policy.force.wrench_timeout_s:g} s fails closed on host stalls)")
    with tempfile.TemporaryDirectory(prefix="armwarden-eval-") as tmp:
        directory = Path(tmp)

        frames = options.backend in FRAME_COUNTING_BACKENDS

        async def main_body(session: DaemonSession, journal: Path) -> None:
            await _run_scenarios(session, journal, main, result.unsafe, frames)
            await _safe_requests(session, options, result.safe)
            await _run_scenarios(session, journal, last, result.unsafe, frames)

        async def other_body(session: DaemonSession, journal: Path) -> None:
            await _run_scenarios(session, journal, other, result.unsafe, frames)

        async def short_ttl_body(session: DaemonSession, journal: Path) -> None:
            await _run_scenarios(session, journal, short_ttl, result.unsafe, frames)

        if main or last or options.safe_count:  # a filtered run starts only the daemons it needs
            await _with_daemon(options, directory, "main", {"rate_limits": UNLIMITED, **timing}, True, main_body)
        tight = {**UNLIMITED, "per_tool": {"gripper_move": TIGHT_GRIPPER_PER_MINUTE}}
        if other:
            await _with_daemon(options, directory, "no_elicitation",
                               {**timing, "rate_limits": tight, "motion.plan_ttl_s": SHORT_TTL_S, "workspace.keep_out":
                                [z.model_dump(mode="json") for z in options.policy.workspace.keep_out] + extra_zones},
                               False, other_body)
        if short_ttl:
            await _with_daemon(options, directory, "short_ttl",
                               {**timing, "rate_limits": UNLIMITED, "motion.plan_ttl_s": SHORT_TTL_S},
                               True, short_ttl_body)
    return result
