"""`armwarden eval`'s fuzzing: generated tool calls, valid and invalid, against the real daemon over
stdio and over streamable HTTP (127.0.0.1, a random free port, an operator token).

The calls come from the tools' own input schemas as the daemon lists them (`tools/list`), through
`armwarden.evaluation.schemas`, drawn by hypothesis under a fixed seed (`--seed`) so that a
finding reproduces. The client answers every approval prompt with DECLINE, except the one reset
the harness itself asks for after each e-stop it (or a generated `estop`) latched — without those
resets the rest of a run would fuzz a latched arm, where nothing could actuate anyway. The daemon
runs the user's policy with rate limits lifted (the calls must reach the tools) and every
approvable action behind approval (`approval.mode: always`, all of `require_for`), so an
approved plan can never happen: any actuation of the arm is a finding. Gripper moves are not
approvable (the policy lets a client move the fingers within their limits): a gripper actuation by
a gripper call with valid arguments is counted apart, as allowed (answered or refused: the journal
counts a call as it reaches the backend, and a backend that has failed refuses it there).

Findings, each counted per transport: a crash (the daemon died, or a call got no answer within
`CALL_TIMEOUT_S`: the run on that transport stops there), an unaudited call (the audit log's
tool-call records, compared in order with the calls sent), an actuation (the actuation journal,
below the Guard), an `estop` not answered (called every `estop_every` calls and at the end). The
daemon's RSS growth (VmRSS at the first answered call and at the last) is reported, not judged.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from collections.abc import AsyncIterator, Callable, Mapping
from contextlib import asynccontextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

import anyio
import anyio.from_thread
import anyio.to_thread
from mcp import Client, MCPError
from mcp import types as mcp_types

from armwarden.backends.ros2.fake_cell_journal import GRIPPER_GOAL
from armwarden.evaluation.daemon_process import (
    DAEMON_COMMAND,
    START_TIMEOUT_S,
    alive,
    http_daemon,
    http_session,
    rss_mb,
    stdio_params,
)
from armwarden.evaluation.journal import JournalReader
from armwarden.evaluation.runner import (
    EVAL_WRENCH_TIMEOUT_S,
    UNLIMITED,
    EvalOptions,
    progress,
    serve_arguments,
    write_policy,
)

#: the transports a run fuzzes, in order
TRANSPORTS = ("stdio", "http")
#: a call not answered within this is a crash finding [s] (generous: a loaded machine is slow, a
#: hung daemon is not)
CALL_TIMEOUT_S = 60.0
#: how long the audit log may take to hold every call's record after the last call [s]
AUDIT_SETTLE_S = 60.0
#: an `estop` check every this many generated calls
ESTOP_EVERY = 100
#: the approvable actions, all behind approval in the fuzzed daemon
APPROVE_ALL = ["execute", "switch_controllers", "reset_estop", "error_recovery", "set_collision_thresholds"]
#: an argument's repr in a finding is cut to this many characters
REPR_CHARS = 160
#: findings kept per kind and transport (every one is counted)
FINDINGS_KEPT = 10
#: plan ids remembered from plan results, offered to execute_plan / get_plan
KNOWN_PLANS = 32
#: generated calls per hypothesis run (each run has its own seed, derived from --seed)
BATCH = 500


@dataclass(frozen=True)
class FuzzOptions:
    calls: int
    seed: int
    transports: tuple[str, ...] = TRANSPORTS
    estop_every: int = ESTOP_EVERY
    daemon_command: tuple[str, ...] = DAEMON_COMMAND
    #: where the policy, audit logs and journals go (None: a temporary directory, removed after)
    workdir: Path | None = None


@dataclass(frozen=True)
class GeneratedCall:
    """One generated call: `mode` valid or invalid (then `mutation` names what was broken);
    `knob` picks a plan id the daemon gave earlier for a valid execute_plan / get_plan."""

    tool: str
    mode: str
    mutation: str | None
    arguments: dict[str, Any]
    knob: int


@dataclass
class Finding:
    kind: str  # "crash", "unaudited", "actuation" or "estop_unanswered"
    call: int  # the call's number on its transport (1-based; generated and harness calls alike)
    tool: str
    arguments: str  # shortened repr
    detail: str


@dataclass
class TransportResult:
    transport: str
    calls: int = 0  # generated calls sent
    harness_calls: int = 0  # the harness's own: first state reads, e-stop checks, resets
    valid: int = 0
    invalid: int = 0
    refused: int = 0  # answered as an error (tool refusal or protocol error)
    crashes: int = 0
    unaudited: int = 0
    actuations: int = 0
    allowed_gripper_actuations: int = 0
    estop_checks: int = 0
    estop_unanswered: int = 0
    resets_refused: int = 0
    #: the daemon's own faults at the end (`get_safety_status`), e.g. a backend it found hung: not
    #: findings of the fuzz (the daemon failed closed), but calls after one met a refusing backend
    faults_at_end: list[str] = field(default_factory=list)
    audit_records: int = 0
    rss_start_mb: float | None = None
    rss_end_mb: float | None = None
    start_s: float = 0.0  # from the daemon's start to its first answered state read
    wall_s: float = 0.0  # the whole transport's run, start-up included
    findings: list[Finding] = field(default_factory=list)

    @property
    def rss_growth_mb(self) -> float | None:
        if self.rss_start_mb is None or self.rss_end_mb is None:
            return None
        return round(self.rss_end_mb - self.rss_start_mb, 1)

    @property
    def finding_count(self) -> int:
        return self.crashes + self.unaudited + self.actuations + self.estop_unanswered

    def note(self, finding: Finding) -> None:
        if sum(f.kind == finding.kind for f in self.findings) < FINDINGS_KEPT:
            self.findings.append(finding)

    def report(self) -> dict[str, Any]:
        data = asdict(self)
        data["rss_growth_mb"] = self.rss_growth_mb
        return data


@dataclass
class FuzzResult:
    per_transport: dict[str, TransportResult] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return all(t.finding_count == 0 for t in self.per_transport.values())

    def report(self) -> dict[str, Any]:
        """The JSON report's `fuzz` object."""
        runs = list(self.per_transport.values())
        growth = [t.rss_growth_mb for t in runs if t.rss_growth_mb is not None]
        return {
            "run": True,
            "calls": sum(t.calls for t in runs),
            "crashes": sum(t.crashes for t in runs),
            "unaudited": sum(t.unaudited for t in runs),
            "actuations": sum(t.actuations for t in runs),
            "estop_unanswered": sum(t.estop_unanswered for t in runs),
            "rss_growth_mb": max(growth) if growth else None,
            "per_transport": {t.transport: t.report() for t in runs},
        }


def short_repr(value: Any, limit: int = REPR_CHARS) -> str:
    """`repr(value)` cut to `limit` characters, with the full length said (a 1 MB string stays readable)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} chars)"


def call_strategy(schemas: Mapping[str, Mapping[str, Any]]) -> Any:
    """Hypothesis strategy of `GeneratedCall`s: a tool, valid or invalid (even odds), its arguments."""
    from hypothesis import strategies as st

    from armwarden.evaluation.schemas import invalid_arguments, valid_arguments

    names = sorted(schemas)
    valid = st.one_of([valid_arguments(schemas[n]).map(lambda a, n=n: (n, "valid", None, a)) for n in names])
    invalid = st.one_of([invalid_arguments(schemas[n]).map(lambda pair, n=n: (n, "invalid", pair[0], pair[1]))
                         for n in names])
    chosen = st.booleans().flatmap(lambda is_valid: valid if is_valid else invalid)  # even odds, drawn first
    return st.builds(lambda call, knob: GeneratedCall(*call, knob=knob), chosen, st.integers(0, 1 << 16))


def as_sent(value: Any) -> Any:
    """`value` as the SDK client puts it on the wire: a non-finite float becomes `null` (pydantic's
    JSON default; JSON has no NaN). A NaN in an optional field thus arrives as a valid `null`."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: as_sent(item) for key, item in value.items()}
    if isinstance(value, list):
        return [as_sent(item) for item in value]
    return value


def _pid_with_argument(argument: str) -> int | None:
    """The process whose command line holds `argument` (the daemon the SDK's stdio client started:
    its own audit log path is unique to it)."""
    wanted = argument.encode()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if wanted in (entry / "cmdline").read_bytes().split(b"\0"):
                return int(entry.name)
        except OSError:
            continue
    return None


def audit_calls(path: Path) -> list[str]:
    """The tool of every call the audit log records, in order: each `tool_call` record, and each
    call a transport refused before the tools (`request_refused` naming a tool, with the refusals
    it says were thinned out before it)."""
    tools: list[str] = []
    if not path.exists():
        return tools
    for line in path.read_bytes().split(b"\n"):  # not splitlines(): U+2028, U+0085 ... sit inside records
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if record.get("event") == "tool_call":
            tools.append(str(record.get("tool")))
        elif record.get("event") == "request_refused" and record.get("tool") is not None:
            left_out = (record.get("extra") or {}).get("not_reported_since_last", 0)
            tools.extend([str(record["tool"])] * (1 + int(left_out)))
    return tools


def unaudited_calls(sent: list[str], recorded: list[str]) -> list[int]:
    """Indexes of the calls in `sent` with no record in `recorded` (both in order; one client
    calling one at a time, so the records follow the calls: a record missing is a gap)."""
    missing, position = [], 0
    for index, tool in enumerate(sent):
        if position < len(recorded) and recorded[position] == tool:
            position += 1
        else:
            missing.append(index)
    return missing


class FuzzSession:
    """One transport's run: sends the calls, checks each answer, the journal and the e-stop."""

    def __init__(self, client: Client, result: TransportResult, journal: Path, pid: int | None,
                 options: FuzzOptions, started: float) -> None:
        self.client, self.result, self.options, self.pid = client, result, options, pid
        self.journal = JournalReader(journal)
        self.sent: list[tuple[str, dict[str, Any]]] = []  # every call, harness's too, in order
        self.known_plans: list[str] = []
        self.accept_reset = False  # set only while the harness's own reset_estop is open
        self.latched = False
        self.broken = False
        self.schemas: dict[str, dict[str, Any]] = {}  # the tools' input schemas, as listed
        self.started = started  # monotonic time the daemon was started

    async def approve(self, context: Any, params: mcp_types.ElicitRequestParams) -> mcp_types.ElicitResult:
        """DECLINE, but for the harness's own reset (`accept_reset`)."""
        if self.accept_reset:
            return mcp_types.ElicitResult(action="accept", content={"approve": True, "operator": "armwarden-eval-fuzz"})
        return mcp_types.ElicitResult(action="decline")

    async def _send(self, tool: str, arguments: dict[str, Any]) -> tuple[bool, dict[str, Any]] | None:
        """(is an error, structured content), or None when no answer came (a crash finding, recorded)."""
        self.sent.append((tool, arguments))
        number = len(self.sent)
        try:
            with anyio.fail_after(CALL_TIMEOUT_S):
                answer = await self.client.call_tool(tool, arguments)
        except MCPError:  # a protocol error reply (-32602 ...): answered
            return True, {}
        except TimeoutError:
            self._crash(number, tool, arguments, f"no answer within {CALL_TIMEOUT_S:g} s")
            return None
        except Exception as exc:  # the connection broke: the daemon died or dropped us
            self._crash(number, tool, arguments, f"{type(exc).__name__}: {exc}"[:300])
            return None
        return bool(answer.is_error), dict(answer.structured_content or {})

    def _crash(self, number: int, tool: str, arguments: dict[str, Any], why: str) -> None:
        running = alive(self.pid)
        self.result.crashes += 1
        self.result.note(Finding("crash", number, tool, short_repr(arguments),
                                 f"{why}; daemon {'still running' if running else 'gone'}"))
        self.broken = True

    def _check_journal(self, tool: str, arguments: dict[str, Any], valid: bool) -> None:
        """Journal lines since the last call are this call's. A gripper actuation is allowed for a
        gripper call whose arguments, as sent (`as_sent`), conform to its schema (`valid`), whatever
        the answer: the journal counts the call as it reaches the backend, before the backend may
        refuse it. The fake ROS cell journals any gripper goal as `GRIPPER_GOAL`."""
        for entry in self.journal.new_entries():
            if entry.kind != "actuation":
                continue  # stops and e-stops are not actuations
            if tool.startswith("gripper_") and entry.call in (tool, GRIPPER_GOAL) and valid:
                self.result.allowed_gripper_actuations += 1
                continue
            self.result.actuations += 1
            self.result.note(Finding("actuation", len(self.sent), tool, short_repr(arguments),
                                     f"the backend got {entry.call} (no plan is ever approved)"))

    async def harness_call(self, tool: str, arguments: dict[str, Any]) -> tuple[bool, dict[str, Any]] | None:
        self.result.harness_calls += 1
        answer = await self._send(tool, arguments)
        self._check_journal(tool, arguments, False)
        return answer

    async def start(self) -> None:
        """Wait until the daemon answers a state read (a stale stream right after start is refused)."""
        with anyio.fail_after(START_TIMEOUT_S):
            while not self.broken:
                answer = await self.harness_call("get_robot_state", {})
                if answer is not None and not answer[0]:
                    break
                await anyio.sleep(0.2)
        self.result.rss_start_mb = rss_mb(self.pid)
        self.result.start_s = round(time.monotonic() - self.started, 1)

    async def check_estop(self) -> None:
        """`estop` must answer (and latch); then the harness releases it (its own approval)."""
        self.result.estop_checks += 1
        answer = await self.harness_call("estop", {"reason": "armwarden eval fuzz: periodic e-stop check"})
        if answer is None:
            self.result.estop_unanswered += 1  # the crash is counted too, as a crash
            self.result.note(Finding("estop_unanswered", len(self.sent), "estop", "{...}", "no answer"))
            return
        if answer[0]:
            self.result.estop_unanswered += 1
            self.result.note(Finding("estop_unanswered", len(self.sent), "estop", "{...}",
                                     f"answered as an error: {short_repr(answer[1])}"))
        self.latched = True
        await self.reset()

    async def reset(self) -> None:
        self.accept_reset = True
        try:
            answer = await self.harness_call("reset_estop", {})
        finally:
            self.accept_reset = False
        if answer is not None and not answer[0] and answer[1].get("status") not in ("rejected", "refused"):
            self.latched = False
        else:
            self.result.resets_refused += 1

    async def fuzz_call(self, call: GeneratedCall) -> None:
        if self.broken or self.result.calls >= self.options.calls:
            return
        arguments = dict(call.arguments)
        if call.mode == "valid" and "plan_id" in arguments and self.known_plans and call.knob % 2 == 0:
            arguments["plan_id"] = self.known_plans[call.knob % len(self.known_plans)]
        self.result.calls += 1
        if call.mode == "valid":
            self.result.valid += 1
        else:
            self.result.invalid += 1
        answer = await self._send(call.tool, arguments)
        if answer is None:
            return
        error, content = answer
        self.result.refused += error
        plan_id = content.get("plan_id")
        if isinstance(plan_id, str) and plan_id not in self.known_plans:
            self.known_plans = [*self.known_plans, plan_id][-KNOWN_PLANS:]
        from armwarden.evaluation.schemas import conforms  # with hypothesis: loaded only when fuzzing

        schema = self.schemas.get(call.tool)
        self._check_journal(call.tool, arguments, schema is not None and conforms(schema, as_sent(arguments)))
        if call.tool == "estop":
            self.latched = True
        if self.result.calls % self.options.estop_every == 0:
            await self.check_estop()
        elif self.latched and not self.broken:
            await self.reset()


def _run_generation(session: FuzzSession, schemas: Mapping[str, Mapping[str, Any]], seed: int) -> None:
    """Hypothesis draws the calls (in this worker thread) and each is sent on the event loop. One
    run of `BATCH` examples per derived seed until the transport's count is reached; the test
    function never fails, so hypothesis neither shrinks nor stops early for a finding."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as hypothesis_seed

    strategy = call_strategy(schemas)
    # slow draws and filtered examples are expected here: no health check applies to a fuzz run
    suppressed = cast("list[HealthCheck]", list(HealthCheck))
    batch = 0
    while not session.broken and session.result.calls < session.options.calls:
        before = session.result.calls

        @settings(max_examples=BATCH, database=None, deadline=None, phases=[Phase.generate],
                  suppress_health_check=suppressed, report_multiple_bugs=False)
        @hypothesis_seed(seed * 1_000_003 + batch)
        @given(strategy)
        def send(call: GeneratedCall) -> None:
            anyio.from_thread.run(session.fuzz_call, call)

        send()
        batch += 1
        if session.result.calls == before:  # nothing more drawn (cannot happen with these schemas)
            break


async def _settle_audit(path: Path, expected: int) -> list[str]:
    """The audit log's calls once it records `expected` of them, or after `AUDIT_SETTLE_S`
    (read-only calls are group-committed: their records follow the answer by a few ms)."""
    deadline = anyio.current_time() + AUDIT_SETTLE_S
    while True:
        recorded = audit_calls(path)
        if len(recorded) >= expected or anyio.current_time() > deadline:
            return recorded
        await anyio.sleep(0.2)


async def _fuzz(session: FuzzSession, audit: Path) -> None:
    result = session.result
    await session.start()
    schemas = {tool.name: dict(tool.input_schema or {}) for tool in (await session.client.list_tools()).tools}
    session.schemas = schemas
    if not session.broken:
        await anyio.to_thread.run_sync(_run_generation, session, schemas, session.options.seed)
    if not session.broken:
        await session.check_estop()  # and at the end
    if not session.broken:
        status = await session.harness_call("get_safety_status", {})
        if status is not None:
            result.faults_at_end = [str(fault)[:300] for fault in status[1].get("faults", [])]
    result.rss_end_mb = rss_mb(session.pid)
    if not session.broken and not alive(session.pid):
        session._crash(len(session.sent), "(none)", {}, "the daemon exited")
    recorded = await _settle_audit(audit, len(session.sent))
    result.audit_records = len(recorded)
    missing = unaudited_calls([tool for tool, _ in session.sent], recorded)
    if session.broken:  # the call that broke the session may have no record; it is a crash already
        missing = [index for index in missing if index != len(session.sent) - 1]
    result.unaudited = len(missing)
    for index in missing:
        tool, arguments = session.sent[index]
        result.note(Finding("unaudited", index + 1, tool, short_repr(arguments), "no tool-call record in the audit log"))
    result.wall_s = round(time.monotonic() - session.started, 1)


@asynccontextmanager
async def _stdio_client(fuzz: FuzzOptions, args: list[str], audit: Path,
                        approve: Callable[..., Any]) -> AsyncIterator[tuple[Client, int | None]]:
    async with Client(stdio_params(fuzz.daemon_command, args), mode="legacy", elicitation_callback=approve) as client:
        yield client, _pid_with_argument(str(audit))


@asynccontextmanager
async def _http_client(fuzz: FuzzOptions, args: list[str], directory: Path,
                       approve: Callable[..., Any]) -> AsyncIterator[tuple[Client, int | None]]:
    from armwarden.transport.tokens import TokenStore

    tokens = directory / "http-tokens.json"
    token = TokenStore.add(tokens, "operator", "eval-fuzz")
    async with (http_daemon(fuzz.daemon_command, args, tokens, directory / "http-stderr.log") as daemon,
                http_session(daemon, token, CALL_TIMEOUT_S, approve) as client):
        yield client, daemon.pid


async def run_fuzz(options: EvalOptions, fuzz: FuzzOptions) -> FuzzResult:
    """`fuzz.calls` generated calls on each of `fuzz.transports`, one daemon each (see the module docstring)."""
    result = FuzzResult()
    overrides = {"rate_limits": UNLIMITED, "approval.mode": "always", "approval.require_for": APPROVE_ALL,
                 "approval.channel": "form",
                 # as in the scenarios' daemons: host stalls must not be what the run measures
                 "force.wrench_timeout_s": max(options.policy.force.wrench_timeout_s, EVAL_WRENCH_TIMEOUT_S)}
    with tempfile.TemporaryDirectory(prefix="armwarden-fuzz-") as tmp:
        directory = Path(tmp) if fuzz.workdir is None else fuzz.workdir
        directory.mkdir(parents=True, exist_ok=True)
        policy = write_policy(options, directory, "fuzz", overrides)
        for transport in fuzz.transports:
            outcome = TransportResult(transport)
            result.per_transport[transport] = outcome
            args = serve_arguments(options, directory, transport, policy)
            audit = directory / f"{transport}-audit.jsonl"
            holder: list[FuzzSession] = []

            async def approve(context: Any, params: mcp_types.ElicitRequestParams,
                              holder: list[FuzzSession] = holder) -> mcp_types.ElicitResult:
                return await holder[0].approve(context, params)

            progress(f"fuzz: starting the daemon over {transport} ({fuzz.calls} generated calls, seed {fuzz.seed})")
            clients = (_stdio_client(fuzz, args, audit, approve) if transport == "stdio"
                       else _http_client(fuzz, args, directory, approve))
            started = time.monotonic()
            try:
                async with clients as (client, pid):
                    session = FuzzSession(client, outcome, directory / f"{transport}-journal.jsonl", pid, fuzz,
                                          started)
                    holder.append(session)
                    await _fuzz(session, audit)
            except Exception as exc:  # the client session itself broke (an ExceptionGroup from its tasks)
                if outcome.calls == 0 and outcome.harness_calls == 0:
                    raise  # the daemon never answered: no run to report (the command's exit 2)
                if outcome.crashes == 0:
                    outcome.crashes += 1
                    sent = len(holder[0].sent) if holder else 0
                    last = holder[0].sent[-1] if holder and holder[0].sent else ("(none)", {})
                    outcome.note(Finding("crash", sent, last[0], short_repr(last[1]),
                                         f"the client session ended: {type(exc).__name__}: {exc}"[:300]))
                outcome.wall_s = round(time.monotonic() - started, 1)
            progress(f"fuzz over {transport}: {outcome.calls} calls, {outcome.finding_count} findings "
                     f"(crashes {outcome.crashes}, unaudited {outcome.unaudited}, actuations {outcome.actuations}, "
                     f"estop unanswered {outcome.estop_unanswered}), RSS growth {outcome.rss_growth_mb} MB, "
                     f"{outcome.wall_s} s")
    return result

