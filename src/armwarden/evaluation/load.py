"""`armwarden eval`'s load run: many HTTP clients at once against the real daemon, with e-stops
through the stop channel while they work.

One daemon over streamable HTTP on 127.0.0.1 (a random free port, a temporary token file) with
its stop channel (`--estop-port`). `clients` sessions run for `duration_s` and then stop by
themselves: a quarter of them operators (plan a safe target, execute it with approval, read the
motion status), the rest observers (the reads an observer's token may make). Every execute needs
approval (`approval.mode: always`); the operators' clients approve, as a human would, and count
what they approved. E-stops are posted to the stop channel at even intervals and timed; an
operator resets each one (approved) so the work goes on.

Reported: calls, throughput, p50/p99 per tool, the e-stops' latency, the daemon's RSS growth.
Judged: no call may fail without an answer (a protocol error or a timeout), every e-stop must be
answered and reset, motions must succeed, the daemon must still run at the end, and the
actuation journal (below the Guard) may count no more actuations than executes the daemon
answered with an execution report, nor those more than the approvals given for executes.
"""

from __future__ import annotations

import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import anyio.to_thread
import numpy as np
from mcp import Client
from mcp import types as mcp_types

from armwarden.evaluation.daemon_process import (
    DAEMON_COMMAND,
    HOST,
    HttpDaemon,
    alive,
    free_port,
    http_daemon,
    http_session,
    rss_mb,
)
from armwarden.evaluation.journal import actuations, read_journal
from armwarden.evaluation.runner import (
    EVAL_WRENCH_TIMEOUT_S,
    UNLIMITED,
    EvalOptions,
    progress,
    safe_goal,
    serve_arguments,
    write_policy,
)
from armwarden.tools.registry import names

#: an e-stop through the stop channel every this many seconds of the run
ESTOP_EVERY_S = 10.0
#: no e-stop this close to the end: its reset must be answered while the operators' sessions last [s]
RESET_MARGIN_S = 2.0
#: a call not answered within this is a failure [s]
CALL_TIMEOUT_S = 60.0
#: the statuses of an execution report: the plan reached the arm (a refusal has none of them)
EXECUTION_STATUSES = ("succeeded", "aborted")


@dataclass
class ToolStats:
    latencies_ms: list[float] = field(default_factory=list)
    refused: int = 0
    failed: int = 0

    def report(self) -> dict[str, Any]:
        values = np.asarray(self.latencies_ms, dtype=float)
        return {"calls": len(self.latencies_ms), "refused": self.refused, "failed": self.failed,
                "p50_ms": round(float(np.percentile(values, 50)), 1) if values.size else None,
                "p99_ms": round(float(np.percentile(values, 99)), 1) if values.size else None}


@dataclass
class LoadResult:
    clients: int = 0
    duration_s: float = 0.0
    per_tool: dict[str, ToolStats] = field(default_factory=lambda: defaultdict(ToolStats))
    estop_ms: list[float] = field(default_factory=list)
    estops_unanswered: int = 0
    approvals: int = 0
    resets: int = 0
    actuations: int = 0
    #: executes answered with an execution report (it reached the arm), and those that succeeded
    executions: int = 0
    succeeded: int = 0
    rss_start_mb: float | None = None
    rss_end_mb: float | None = None
    alive_at_end: bool = False
    failures: list[str] = field(default_factory=list)

    @property
    def calls(self) -> int:
        return sum(len(s.latencies_ms) for s in self.per_tool.values())

    @property
    def ok(self) -> bool:
        failed = sum(s.failed for s in self.per_tool.values())
        # every actuation is an execute the daemon answered with its report (an approved plan that
        # ran), and the work went on: every e-stop was reset and motions succeeded
        return failed == 0 and self.estops_unanswered == 0 and self.alive_at_end and bool(self.estop_ms) \
            and self.actuations <= self.executions <= self.approvals - self.resets \
            and self.resets == len(self.estop_ms) and self.succeeded > 0

    def report(self) -> dict[str, Any]:
        estops = np.asarray(self.estop_ms, dtype=float)
        growth = None if self.rss_start_mb is None or self.rss_end_mb is None else \
            round(self.rss_end_mb - self.rss_start_mb, 1)
        return {
            "run": True, "passed": self.ok, "clients": self.clients, "duration_s": self.duration_s,
            "calls": self.calls, "throughput_per_s": round(self.calls / self.duration_s, 1) if self.duration_s else None,
            "per_tool": {tool: stats.report() for tool, stats in sorted(self.per_tool.items())},
            "estop": {"count": int(estops.size), "unanswered": self.estops_unanswered,
                      "p50_ms": round(float(np.percentile(estops, 50)), 1) if estops.size else None,
                      "max_ms": round(float(estops.max()), 1) if estops.size else None},
            "approvals": self.approvals, "resets": self.resets, "actuations": self.actuations,
            "executions": self.executions, "succeeded": self.succeeded,
            "rss_growth_mb": growth, "alive_at_end": self.alive_at_end, "failures": self.failures[:10],
        }


class LoadClient:
    """One client's loop until the deadline: calls timed and counted by tool."""

    def __init__(self, client: Client, result: LoadResult, deadline: float) -> None:
        self.client = client
        self.result = result
        self.deadline = deadline

    async def call(self, tool: str, arguments: dict[str, Any]) -> dict[str, Any] | None:
        """The structured answer of an answered call (None when refused or failed)."""
        stats = self.result.per_tool[tool]
        started = time.perf_counter()
        try:
            with anyio.fail_after(CALL_TIMEOUT_S):
                answer = await self.client.call_tool(tool, arguments)
        except Exception as exc:  # no answer: a protocol error or a timeout
            stats.latencies_ms.append((time.perf_counter() - started) * 1000.0)
            stats.failed += 1
            self.result.failures.append(f"{tool}: {type(exc).__name__}: {exc}"[:200])
            return None
        stats.latencies_ms.append((time.perf_counter() - started) * 1000.0)
        content = dict(answer.structured_content or {})
        if tool == "execute_plan" and content.get("status") in EXECUTION_STATUSES:
            self.result.executions += 1  # it reached the arm, whatever became of it
            self.result.succeeded += content["status"] == "succeeded"
        if answer.is_error or content.get("status") in ("rejected", "aborted"):
            stats.refused += 1
            return None
        return content

    def running(self) -> bool:
        return time.monotonic() < self.deadline


def observer_reads() -> frozenset[str]:
    """The tools an observer's token may call that only read, pictures aside (the catalogue's)."""
    return names(lambda spec: spec.observer_may_call and spec.hints.read_only and not spec.picture)


async def _observer(client: LoadClient, rng: np.random.Generator) -> None:
    """Reads, drawn from the observer's reads the daemon serves that need no arguments."""
    listed = await client.client.list_tools()
    reads = sorted(t.name for t in listed.tools
                   if t.name in observer_reads() and not (t.input_schema or {}).get("required"))
    while client.running() and reads:
        await client.call(str(rng.choice(reads)), {})


async def _operator(client: LoadClient, options: EvalOptions, robot: Any, rng: np.random.Generator) -> None:
    while client.running():
        goal = safe_goal(options.policy, robot, rng)
        plan = await client.call("plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
        if plan is not None and plan.get("plan_id"):
            await client.call("execute_plan", {"plan_id": plan["plan_id"]})
        await client.call("get_motion_status", {})


async def _estops(daemon_channel: str, token: str, result: LoadResult, operator: LoadClient, every_s: float) -> None:
    """An e-stop through the stop channel every `every_s` until the deadline, each reset by an operator.

    The first comes within the time left once the sessions are open, whatever their opening took
    (16 sessions on a loaded machine took longer than a short run's `every_s` allowed): a run
    with no e-stop measured nothing of it."""
    from armwarden.stopchannel.client import EStopRequestError, send_estop

    wait_s = min(every_s, max(0.0, (operator.deadline - time.monotonic() - RESET_MARGIN_S) / 2))
    first = True
    while True:
        await anyio.sleep(wait_s)
        wait_s = every_s
        if not first and operator.deadline - time.monotonic() < RESET_MARGIN_S:  # its reset comes before the end
            return
        first = False
        started = time.perf_counter()
        try:
            answer = await anyio.to_thread.run_sync(send_estop, daemon_channel, token, "eval: load e-stop")
        except EStopRequestError as exc:
            result.estops_unanswered += 1
            result.failures.append(f"e-stop: {exc}"[:200])
            continue
        result.estop_ms.append((time.perf_counter() - started) * 1000.0)
        if not answer.get("estopped"):
            result.estops_unanswered += 1
        if await operator.call("reset_estop", {}) is not None:
            result.resets += 1


async def run_load(options: EvalOptions, clients: int, duration_s: float) -> LoadResult:
    from armwarden.preflight import load_runtime_model
    from armwarden.transport.tokens import TokenStore

    result = LoadResult(clients=clients, duration_s=duration_s)
    robot = load_runtime_model(options.policy, str(options.policy_path)).robot
    operators = max(1, clients // 4)
    overrides = {"rate_limits": UNLIMITED, "approval.mode": "always", "approval.require_for": ["execute", "reset_estop"],
                 "approval.channel": "form", "force.wrench_timeout_s": EVAL_WRENCH_TIMEOUT_S}
    with tempfile.TemporaryDirectory(prefix="armwarden-load-") as tmp:
        directory = Path(tmp)
        policy = write_policy(options, directory, "load", overrides)
        tokens = directory / "tokens.json"
        roles = ["operator"] * operators + ["observer"] * (clients - operators)
        keys = [TokenStore.add(tokens, role, f"load-{i}") for i, role in enumerate(roles)]
        stop_port = free_port()
        args = serve_arguments(options, directory, "load", policy)
        progress(f"load: {clients} HTTP clients ({operators} operators) for {duration_s:g} s, an e-stop every "
                 f"{ESTOP_EVERY_S:g} s through the stop channel")

        async def approve(context: Any, params: mcp_types.ElicitRequestParams) -> mcp_types.ElicitResult:
            result.approvals += 1
            return mcp_types.ElicitResult(action="accept", content={"approve": True, "operator": "armwarden-eval"})

        async with http_daemon(DAEMON_COMMAND, args, tokens, directory / "load-stderr.log",
                               ("--estop-port", str(stop_port))) as daemon:
            await _drive(daemon, keys, roles, approve, options, robot, result, f"http://{HOST}:{stop_port}/estop")
            result.alive_at_end = alive(daemon.pid)
            result.rss_end_mb = rss_mb(daemon.pid)
        result.actuations = len(actuations(read_journal(directory / "load-journal.jsonl")))
    progress(f"load: {result.calls} calls ({result.calls / duration_s:.1f}/s), e-stops {len(result.estop_ms)} "
             f"answered, {result.estops_unanswered} not; actuations {result.actuations} for {result.approvals} "
             f"approvals ({result.resets} of them resets)")
    return result


async def _drive(daemon: HttpDaemon, keys: list[str], roles: list[str], approve: Any, options: EvalOptions,
                 robot: Any, result: LoadResult, channel: str) -> None:
    """Every client's session and loop, and the e-stops, until the deadline."""
    result.rss_start_mb = rss_mb(daemon.pid)
    deadline = time.monotonic() + result.duration_s
    rng = np.random.default_rng(options.seed)
    seeds = rng.integers(0, 2**31, size=len(keys))
    observer_key = next((k for k, r in zip(keys, roles, strict=True) if r == "observer"), keys[0])

    first_operator: list[LoadClient] = []
    ready = anyio.Event()

    async def one(index: int) -> None:
        role = roles[index]
        async with http_session(daemon, keys[index], CALL_TIMEOUT_S, approve if role == "operator" else None) as c:
            client = LoadClient(c, result, deadline)
            own = np.random.default_rng(int(seeds[index]))
            if role == "operator":
                if index == 0:  # the one that resets the e-stops
                    first_operator.append(client)
                    ready.set()
                await _operator(client, options, robot, own)
            else:
                await _observer(client, own)

    async with anyio.create_task_group() as group:
        for index in range(len(keys)):
            group.start_soon(one, index)
        await ready.wait()
        every = min(ESTOP_EVERY_S, result.duration_s / 2)
        group.start_soon(_estops, channel, observer_key, result, first_operator[0], every)
