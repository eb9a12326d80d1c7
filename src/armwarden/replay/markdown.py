"""The replay report as markdown: the executed motions the candidate would have rejected first,
then those that would now need a human's approval, every replayed plan, the speed changes, what
could not be replayed and why, how a re-planned original differs from the record (with
`--original`), the totals, and a footnote on detour-planned outcomes when there are any.
Deterministic: fixed float formatting, log order, sorted codes, nothing about the run itself.
"""

from __future__ import annotations

from collections.abc import Sequence

from armwarden.replay.records import Execution, Outcome
from armwarden.replay.report import (
    DETOUR_FOOTNOTE,
    PlanRow,
    ReplayReport,
    describe_request,
    scalings_text,
    table_cell,
)


def render_markdown(report: ReplayReport) -> str:
    """The report as markdown (module docstring for its order)."""
    lines: list[str] = [f"# Audit replay of {report.log.name} under {report.candidate.name}", ""]
    lines += _header(report)
    lines += ["", "## Executed motions the candidate policy would reject", ""]
    lines += _executions(report.executed_now("rejected"))
    unreplayed = [run for run, row in report.moved() if row is None or not row.replayed]
    if unreplayed:
        lines += ["", f"{len(unreplayed)} executed motion(s) could not be replayed (their plans are under "
                  "\"Not replayable\" below, or were planned before the log begins): "
                  + ", ".join(f"line {run.line} ({run.plan_id})" for run in unreplayed) + "."]
    lines += ["", "## Executed motions that would now need a human's approval", ""]
    lines += _executions(report.executed_now("needs_approval"))
    lines += ["", "## Plans", ""]
    lines += _plans(report)
    lines += ["", "## Speed changes", ""]
    lines += _speeds(report)
    lines += ["", "## Not replayable", ""]
    lines += _not_replayable(report)
    if report.original is not None:
        lines += _fidelity(report)
    lines += ["", "## Totals", ""]
    lines += _totals(report)
    if any(row.replayed and (row.candidate.detour or row.original.detour)  # type: ignore[union-attr]
           for row in report.rows):
        lines += ["", DETOUR_FOOTNOTE]
    return "\n".join(lines) + "\n"

def _header(report: ReplayReport) -> list[str]:
    log = report.log
    if log.verdict.ok:
        chain = f"chain intact, {len(log.records)} records"
    else:
        chain = (f"**chain broken at line {log.first_untrusted_line}: {log.verdict.reason}** — nothing from line "
                 f"{log.first_untrusted_line} on is trusted; replayed lines 1–{log.trusted_lines} only "
                 f"({len(log.records)} records)")
    out = [f"- Log: {log.name} — {chain}", f"- Candidate policy: {report.candidate.name} ({report.candidate.digest})"]
    digests = ", ".join(report.recorded_digests) if report.recorded_digests else "none (an older log)"
    if report.original is None:
        out.append(f"- Original outcomes: as recorded in the log (policy digests recorded: {digests})")
    else:
        matches = "matches" if report.original.digest in report.recorded_digests else "does NOT match"
        out.append(f"- Original outcomes: re-planned under {report.original.name} ({report.original.digest}; "
                   f"{matches} the digests recorded: {digests})")
    replayed = sum(1 for row in report.rows if row.replayed)
    out.append(f"- Plan requests: {len(report.rows)} ({replayed} replayed, {len(report.rows) - replayed} not replayable)")
    return out

def _executions(found: Sequence[tuple[Execution, PlanRow]]) -> list[str]:
    if not found:
        return ["None."]
    out = ["| line | seq | plan_id | ran | plan (line) | request | original | candidate | codes added |",
           "|---:|---:|---|---|---:|---|---|---|---|"]
    for run, row in found:
        assert row.original is not None and row.candidate is not None
        out.append(f"| {run.line} | {run.seq} | {run.plan_id} | {run.status} | {row.call.line} | "
                   f"{describe_request(row.call)} | {_outcome_text(row.original)} | "
                   f"{_outcome_text(row.candidate)} | {_codes(row.codes_added)} |")
    return out

def _plans(report: ReplayReport) -> list[str]:
    rows = [row for row in report.rows if row.replayed]
    if not rows:
        return ["None replayed."]
    out = ["| line | seq | tool | request | executed | original | candidate | change | codes added | codes removed |",
           "|---:|---:|---|---|---|---|---|---|---|---|"]
    ran = {run.plan_id: run.status for run in report.executions}
    for row in rows:
        assert row.original is not None and row.candidate is not None
        executed = ran.get(row.call.plan_id or "", "—")
        out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {describe_request(row.call)} | {executed} | "
                   f"{_outcome_text(row.original)} | {_outcome_text(row.candidate)} | {_change_text(row.change)} | "
                   f"{_codes(row.codes_added)} | {_codes(row.codes_removed)} |")
    return out

def _speeds(report: ReplayReport) -> list[str]:
    rows = [row for row in report.rows if row.speed_changed]
    if not rows:
        return ["None (the velocity and acceleration scalings after the caps are the same)."]
    out = ["| line | seq | tool | request | velocity scaling | acceleration scaling |", "|---:|---:|---|---|---|---|"]
    for row in rows:
        assert row.original is not None and row.candidate is not None
        (v0, a0), (v1, a1) = scalings_text(row.original), scalings_text(row.candidate)
        out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {describe_request(row.call)} | "
                   f"{v0} → {v1} | {a0} → {a1} |")
    return out

def _not_replayable(report: ReplayReport) -> list[str]:
    rows = [row for row in report.rows if not row.replayed]
    if not rows:
        return ["None."]
    out = ["| line | seq | tool | recorded | reason |", "|---:|---:|---|---|---|"]
    for row in rows:
        recorded = _outcome_text(row.call.recorded) if row.call.recorded is not None else (row.call.refusal or "—")
        out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {table_cell(recorded)} | {table_cell(row.reason or '')} |")
    return out

def _fidelity(report: ReplayReport) -> list[str]:
    differing = [row for row in report.rows if row.differs_from_record]
    if not differing:
        return []
    out = ["", "## Re-planned original differs from the record", "",
           "The original policy, re-planned here, does not give what the daemon answered at the time (another "
           "policy was in force, or the planner's result depends on the machine):", "",
           "| line | seq | tool | recorded | re-planned |", "|---:|---:|---|---|---|"]
    for row in differing:
        assert row.call.recorded is not None and row.original is not None
        out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {_outcome_text(row.call.recorded)} | "
                   f"{_outcome_text(row.original)} |")
    return out

def _totals(report: ReplayReport) -> list[str]:
    totals = report.totals()
    return ["| newly rejected | newly allowed | newly needing approval | unchanged | not replayable | "
            "executed motions now rejected | speed changed |",
            "|---:|---:|---:|---:|---:|---:|---:|",
            f"| {totals['newly_rejected']} | {totals['newly_allowed']} | {totals['newly_needs_approval']} | "
            f"{totals['unchanged']} | {totals['not_replayable']} | {totals['executed_newly_rejected']} | "
            f"{totals['speed_changed']} |"]


def _codes(codes: Sequence[str]) -> str:
    return ", ".join(codes) if codes else "—"


def _outcome_text(outcome: Outcome) -> str:
    text = outcome.status + (f" ({', '.join(outcome.codes)})" if outcome.codes else "")
    return text + (" †" if outcome.detour else "")


def _change_text(change: str | None) -> str:
    return {"newly_rejected": "**newly rejected**", "newly_allowed": "newly allowed",
            "newly_needs_approval": "newly needs approval", "unchanged": "unchanged"}.get(change or "", "—")
