"""Reading what a replay needs from an audit log: the trusted records, the plan calls, the executions.

Trust first: the chain is verified (`verify_file`) before any record is read. A log that does not
verify is refused (`BrokenLog`) unless the caller allows it; then only the lines before the first
bad one are read, and nothing from that line on is used. Recovered torn fragments (lines a
``recovery`` record names) are skipped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any

from armwarden.audit import AUDIT_KEY_ENV, VerifyReport, verify_file
from armwarden.audit.chain import DECODER
from armwarden.core.errors import ArmWardenError
from armwarden.tools import TOOLS

#: the planning tools and the planner kind each one asks for
PLAN_TOOLS = {spec.name: spec.plan_kind for spec in TOOLS if spec.plan_kind is not None}
#: execution statuses of a motion that actually moved the arm (a dry run moved nothing)
MOVED = ("succeeded", "aborted")


class BrokenLog(ArmWardenError):
    """The log's chain does not verify (or the log cannot be read) and a broken log was not allowed."""


@dataclass(frozen=True)
class Outcome:
    """A plan's verdict as the report compares it: status and the sorted violation codes."""

    status: str  # ok | needs_approval | rejected
    codes: tuple[str, ...]
    detour: bool = False  # the detour planner decided it (see `armwarden.replay`)
    #: the scalings the planner used, after the policy's caps (None: not known, e.g. an older record)
    velocity_scaling: float | None = None
    acceleration_scaling: float | None = None


@dataclass(frozen=True)
class PlanCall:
    """One recorded `plan_*` call."""

    line: int
    seq: int
    tool: str
    kind: str
    arguments: Any
    plan_id: str | None
    recorded: Outcome | None  # the summary the daemon answered (None: it answered none)
    refusal: str | None  # what happened instead of a summary (a refusal code or the outcome)
    facts: dict[str, Any] | None  # the record's `extra.replay` (None: written before it existed)


@dataclass(frozen=True)
class Execution:
    """One recorded `execute_plan` call that ran (or dry-ran) a plan."""

    line: int
    seq: int
    plan_id: str
    status: str  # succeeded | aborted | dry_run


@dataclass(frozen=True)
class TrustedLog:
    """The records a replay may use, with the verdict on the chain."""

    name: str
    verdict: VerifyReport
    trusted_lines: int  # lines 1..trusted_lines are used; nothing after
    records: tuple[tuple[int, dict[str, Any]], ...]  # (line number, record)

    @property
    def first_untrusted_line(self) -> int | None:
        return self.verdict.first_bad_line

    def plan_calls(self) -> list[PlanCall]:
        return [call for line, record in self.records if (call := _plan_call(line, record)) is not None]

    def executions(self) -> list[Execution]:
        return [run for line, record in self.records if (run := _execution(line, record)) is not None]

    def policy_digests(self) -> list[str]:
        """Every policy digest the log records (start-up records and planning calls), sorted."""
        found: set[str] = set()
        for _, record in self.records:
            extra = record.get("extra")
            if not isinstance(extra, dict):
                continue
            replay = extra.get("replay")
            for digest in (extra.get("policy_digest"), replay.get("policy_digest") if isinstance(replay, dict) else None):
                if isinstance(digest, str):
                    found.add(digest)
        return sorted(found)


def read_trusted(path: str | os.PathLike[str], key: bytes | None = None, *, allow_broken: bool = False) -> TrustedLog:
    """The log's trusted records. Raises `BrokenLog` if it cannot be read, or if its chain is
    broken and `allow_broken` is False."""
    name = os.path.basename(os.fspath(path))
    try:
        verdict = verify_file(path, key)
    except (OSError, ArmWardenError) as exc:
        raise BrokenLog(f"cannot read {os.fspath(path)}: {exc}") from exc
    if not verdict.ok and not allow_broken:
        hint = ""
        if key is None and verdict.reason == "hash mismatch" and verdict.first_bad_line == 1:
            hint = f" (no HMAC key given; set {AUDIT_KEY_ENV} if this log is keyed)"
        raise BrokenLog(f"{name}: chain broken at line {verdict.first_bad_line}: {verdict.reason}{hint}; refusing to "
                        "replay a log that does not verify (--allow-broken replays the lines before it)")
    trusted = (verdict.first_bad_line - 1) if verdict.first_bad_line is not None else None
    records: list[tuple[int, dict[str, Any]]] = []
    with open(path, "rb") as stream:
        for line, raw in enumerate(stream, start=1):
            if trusted is not None and line > trusted:
                break
            if line in verdict.recovered_lines:
                continue
            record = DECODER.decode(raw.decode("utf-8"))  # verified above: every trusted line parses
            records.append((line, record))
    return TrustedLog(name, verdict, trusted if trusted is not None else (records[-1][0] if records else 0), tuple(records))


def outcome_of_summary(summary: Any) -> Outcome | None:
    """The outcome a recorded `PlanSummary` states (None if it is not one)."""
    if not isinstance(summary, dict) or summary.get("status") not in ("ok", "needs_approval", "rejected"):
        return None
    violations = summary.get("violations")
    codes = {str(v["code"]) for v in violations if isinstance(v, dict) and isinstance(v.get("code"), str)} \
        if isinstance(violations, list) else set()
    return Outcome(summary["status"], tuple(sorted(codes)))


def _extra(record: dict[str, Any]) -> dict[str, Any]:
    extra = record.get("extra")
    return extra if isinstance(extra, dict) else {}


def _plan_call(line: int, record: dict[str, Any]) -> PlanCall | None:
    tool = record.get("tool")
    if record.get("event") != "tool_call" or tool not in PLAN_TOOLS:
        return None
    extra = _extra(record)
    summary = extra.get("result")
    facts = extra.get("replay")
    facts = facts if isinstance(facts, dict) else None
    recorded = outcome_of_summary(summary)
    planner = facts.get("planner") if facts is not None else None
    if recorded is not None and isinstance(planner, dict):
        recorded = replace(recorded, velocity_scaling=_number(planner.get("velocity_scaling")),
                           acceleration_scaling=_number(planner.get("acceleration_scaling")))
    plan_id = summary.get("plan_id") if isinstance(summary, dict) and isinstance(summary.get("plan_id"), str) else None
    refusal = None
    if recorded is None:
        code = extra.get("code")
        refusal = f"{record.get('outcome')} ({code})" if isinstance(code, str) else str(record.get("outcome"))
    return PlanCall(line, int(record["seq"]), tool, PLAN_TOOLS[tool], record.get("arguments"), plan_id, recorded,
                    refusal, facts)


def _number(value: Any) -> float | None:
    return float(value) if type(value) in (int, float) else None


def _execution(line: int, record: dict[str, Any]) -> Execution | None:
    if record.get("event") != "tool_call" or record.get("tool") != "execute_plan" or record.get("outcome") != "ok":
        return None
    result = _extra(record).get("result")
    if not isinstance(result, dict) or not isinstance(result.get("plan_id"), str) or not isinstance(result.get("status"), str):
        return None
    return Execution(line, int(record["seq"]), result["plan_id"], result["status"])
