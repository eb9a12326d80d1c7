"""The replay report: per plan, the original outcome against the candidate's, and what that means.

Each replayed plan falls in exactly one class, by how its status moved on the scale
ok < needs_approval < rejected:

- ``newly_rejected``: the candidate rejects it and the original did not;
- ``newly_needs_approval``: ok before, a human must approve it now;
- ``newly_allowed``: the candidate is less strict (rejected → needs_approval or ok,
  needs_approval → ok);
- ``unchanged``: same status (the violation codes may still differ; the report shows which).

Executions that moved the arm and whose plan the candidate rejects come first: those are the
motions the candidate policy would have stopped. A speed cap never rejects a plan (a scaling above
the cap is clamped to it), so what a changed speed cap does shows under "Speed changes": the plans
whose velocity or acceleration scaling, after the caps, differs. Everything is rendered deterministically: log
order, sorted codes, fixed float formatting, nothing about the run itself (no time, no host).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from armwarden.replay.records import MOVED, Execution, Outcome, PlanCall, TrustedLog

RANK = {"ok": 0, "needs_approval": 1, "rejected": 2}
CHANGES: tuple[str, ...] = ("newly_rejected", "newly_allowed", "newly_needs_approval", "unchanged")
DETOUR_FOOTNOTE = ("† the straight line was blocked and the detour planner decided this outcome within the policy's "
                   "motion.planning_time_s. Its search is seeded from the request and start state, so it repeats "
                   "exactly when it finishes within that budget; a search the budget cut short may end differently "
                   "on a slower or busier machine.")


def change_of(original: Outcome, candidate: Outcome) -> str:
    """The class of a replayed plan (module docstring)."""
    before, after = RANK[original.status], RANK[candidate.status]
    if after == before:
        return "unchanged"
    if candidate.status == "rejected":
        return "newly_rejected"
    if after > before:
        return "newly_needs_approval"
    return "newly_allowed"


@dataclass(frozen=True)
class PlanRow:
    """One recorded plan call and what the replay made of it."""

    call: PlanCall
    original: Outcome | None
    candidate: Outcome | None
    reason: str | None = None  # why it was not replayed (then original/candidate may be None)

    @property
    def replayed(self) -> bool:
        return self.reason is None and self.original is not None and self.candidate is not None

    @property
    def change(self) -> str | None:
        if not self.replayed:
            return None
        assert self.original is not None and self.candidate is not None
        return change_of(self.original, self.candidate)

    @property
    def codes_added(self) -> tuple[str, ...]:
        if not self.replayed:
            return ()
        assert self.original is not None and self.candidate is not None
        return tuple(sorted(set(self.candidate.codes) - set(self.original.codes)))

    @property
    def codes_removed(self) -> tuple[str, ...]:
        if not self.replayed:
            return ()
        assert self.original is not None and self.candidate is not None
        return tuple(sorted(set(self.original.codes) - set(self.candidate.codes)))

    @property
    def speed_changed(self) -> bool:
        """The scalings the planner used (after the caps) differ, to the report's precision."""
        if not self.replayed:
            return False
        assert self.original is not None and self.candidate is not None
        return _scalings(self.original) != _scalings(self.candidate) and None not in (
            *_scalings(self.original), *_scalings(self.candidate))

    @property
    def differs_from_record(self) -> bool:
        """With a re-planned original: it disagrees with what the daemon answered at the time."""
        recorded = self.call.recorded
        return self.original is not None and recorded is not None and (
            recorded.status, recorded.codes) != (self.original.status, self.original.codes)


@dataclass(frozen=True)
class PolicyRef:
    name: str
    digest: str


@dataclass(frozen=True)
class ReplayReport:
    log: TrustedLog
    candidate: PolicyRef
    original: PolicyRef | None  # None: the recorded outcomes are the original
    rows: tuple[PlanRow, ...]
    executions: tuple[Execution, ...]
    recorded_digests: tuple[str, ...] = field(default=())

    # -- derived ---------------------------------------------------------------------------
    def row_of_plan(self, plan_id: str) -> PlanRow | None:
        return next((row for row in self.rows if row.call.plan_id == plan_id), None)

    def moved(self) -> list[tuple[Execution, PlanRow | None]]:
        """Executions that moved the arm, with the row of the plan they ran (None: plan not in the log)."""
        return [(run, self.row_of_plan(run.plan_id)) for run in self.executions if run.status in MOVED]

    def executed_now(self, status: str) -> list[tuple[Execution, PlanRow]]:
        """Executions that moved the arm and whose plan the candidate now gives `status` (for the
        first time: the original did not)."""
        found = []
        for run, row in self.moved():
            if row is not None and row.replayed and row.candidate is not None and row.original is not None \
                    and row.candidate.status == status and row.original.status != status:
                found.append((run, row))
        return found

    def totals(self) -> dict[str, int]:
        counts: dict[str, int] = dict.fromkeys(CHANGES, 0)
        for row in self.rows:
            if row.change is not None:
                counts[row.change] += 1
        counts["not_replayable"] = sum(1 for row in self.rows if not row.replayed)
        counts["speed_changed"] = sum(1 for row in self.rows if row.speed_changed)
        counts["executed_newly_rejected"] = len(self.executed_now("rejected"))
        return counts

    # -- JSON ------------------------------------------------------------------------------
    def to_data(self) -> dict[str, Any]:
        log = self.log
        return {
            "log": {"name": log.name, "chain_intact": log.verdict.ok, "records": len(log.records),
                    "trusted_lines": log.trusted_lines, "first_untrusted_line": log.first_untrusted_line,
                    "broken_reason": log.verdict.reason},
            "candidate_policy": {"name": self.candidate.name, "digest": self.candidate.digest},
            "original": ({"source": "recorded", "recorded_digests": list(self.recorded_digests)} if self.original is None
                         else {"source": "policy", "name": self.original.name, "digest": self.original.digest,
                               "recorded_digests": list(self.recorded_digests)}),
            "executed_newly_rejected": [_execution_data(run, row) for run, row in self.executed_now("rejected")],
            "executed_newly_needs_approval": [_execution_data(run, row) for run, row in self.executed_now("needs_approval")],
            "plans": [_row_data(row) for row in self.rows],
            "totals": self.totals(),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_data(), indent=2, sort_keys=True, ensure_ascii=False, allow_nan=False) + "\n"

    # -- markdown --------------------------------------------------------------------------
    def to_markdown(self) -> str:
        lines: list[str] = [f"# Audit replay of {self.log.name} under {self.candidate.name}", ""]
        lines += self._header()
        lines += ["", "## Executed motions the candidate policy would reject", ""]
        lines += self._executions(self.executed_now("rejected"))
        unreplayed = [run for run, row in self.moved() if row is None or not row.replayed]
        if unreplayed:
            lines += ["", f"{len(unreplayed)} executed motion(s) could not be replayed (their plans are under "
                      "\"Not replayable\" below, or were planned before the log begins): "
                      + ", ".join(f"line {run.line} ({run.plan_id})" for run in unreplayed) + "."]
        lines += ["", "## Executed motions that would now need a human's approval", ""]
        lines += self._executions(self.executed_now("needs_approval"))
        lines += ["", "## Plans", ""]
        lines += self._plans()
        lines += ["", "## Speed changes", ""]
        lines += self._speeds()
        lines += ["", "## Not replayable", ""]
        lines += self._not_replayable()
        if self.original is not None:
            lines += self._fidelity()
        lines += ["", "## Totals", ""]
        lines += self._totals()
        if any(row.replayed and (row.candidate.detour or row.original.detour)  # type: ignore[union-attr]
               for row in self.rows):
            lines += ["", DETOUR_FOOTNOTE]
        return "\n".join(lines) + "\n"

    def _header(self) -> list[str]:
        log = self.log
        if log.verdict.ok:
            chain = f"chain intact, {len(log.records)} records"
        else:
            chain = (f"**chain broken at line {log.first_untrusted_line}: {log.verdict.reason}** — nothing from line "
                     f"{log.first_untrusted_line} on is trusted; replayed lines 1–{log.trusted_lines} only "
                     f"({len(log.records)} records)")
        out = [f"- Log: {log.name} — {chain}", f"- Candidate policy: {self.candidate.name} ({self.candidate.digest})"]
        digests = ", ".join(self.recorded_digests) if self.recorded_digests else "none (an older log)"
        if self.original is None:
            out.append(f"- Original outcomes: as recorded in the log (policy digests recorded: {digests})")
        else:
            matches = "matches" if self.original.digest in self.recorded_digests else "does NOT match"
            out.append(f"- Original outcomes: re-planned under {self.original.name} ({self.original.digest}; "
                       f"{matches} the digests recorded: {digests})")
        replayed = sum(1 for row in self.rows if row.replayed)
        out.append(f"- Plan requests: {len(self.rows)} ({replayed} replayed, {len(self.rows) - replayed} not replayable)")
        return out

    @staticmethod
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

    def _plans(self) -> list[str]:
        rows = [row for row in self.rows if row.replayed]
        if not rows:
            return ["None replayed."]
        out = ["| line | seq | tool | request | executed | original | candidate | change | codes added | codes removed |",
               "|---:|---:|---|---|---|---|---|---|---|---|"]
        ran = {run.plan_id: run.status for run in self.executions}
        for row in rows:
            assert row.original is not None and row.candidate is not None
            executed = ran.get(row.call.plan_id or "", "—")
            out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {describe_request(row.call)} | {executed} | "
                       f"{_outcome_text(row.original)} | {_outcome_text(row.candidate)} | {_change_text(row.change)} | "
                       f"{_codes(row.codes_added)} | {_codes(row.codes_removed)} |")
        return out

    def _speeds(self) -> list[str]:
        rows = [row for row in self.rows if row.speed_changed]
        if not rows:
            return ["None (the velocity and acceleration scalings after the caps are the same)."]
        out = ["| line | seq | tool | request | velocity scaling | acceleration scaling |", "|---:|---:|---|---|---|---|"]
        for row in rows:
            assert row.original is not None and row.candidate is not None
            (v0, a0), (v1, a1) = _scalings(row.original), _scalings(row.candidate)
            out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {describe_request(row.call)} | "
                       f"{v0} → {v1} | {a0} → {a1} |")
        return out

    def _not_replayable(self) -> list[str]:
        rows = [row for row in self.rows if not row.replayed]
        if not rows:
            return ["None."]
        out = ["| line | seq | tool | recorded | reason |", "|---:|---:|---|---|---|"]
        for row in rows:
            recorded = _outcome_text(row.call.recorded) if row.call.recorded is not None else (row.call.refusal or "—")
            out.append(f"| {row.call.line} | {row.call.seq} | {row.call.tool} | {_cell(recorded)} | {_cell(row.reason or '')} |")
        return out

    def _fidelity(self) -> list[str]:
        differing = [row for row in self.rows if row.differs_from_record]
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

    def _totals(self) -> list[str]:
        totals = self.totals()
        return ["| newly rejected | newly allowed | newly needing approval | unchanged | not replayable | "
                "executed motions now rejected | speed changed |",
                "|---:|---:|---:|---:|---:|---:|---:|",
                f"| {totals['newly_rejected']} | {totals['newly_allowed']} | {totals['newly_needs_approval']} | "
                f"{totals['unchanged']} | {totals['not_replayable']} | {totals['executed_newly_rejected']} | "
                f"{totals['speed_changed']} |"]


# ------------------------------------------------------------------------------------ helpers
def describe_request(call: PlanCall) -> str:
    """A short, fixed-format description of what was asked (from the replay data, else the arguments)."""
    request = (call.facts or {}).get("request")
    if not isinstance(request, dict):
        request = call.arguments if isinstance(call.arguments, dict) else {}
    try:
        if call.kind == "joints":
            text = "joints " + _vector(request["joint_positions"])
        elif call.kind == "pose":
            target = request.get("target") or request
            position = target["position"]
            position = [position["x"], position["y"], position["z"]] if isinstance(position, dict) else position
            text = "pose " + _vector(position, "(", ")")
        else:
            text = f"{len(request['waypoints'])} waypoint(s)"
    except (KeyError, TypeError, ValueError):
        text = "?"
    scaling = request.get("velocity_scaling") if isinstance(request, dict) else None
    if type(scaling) in (int, float):
        text += f", velocity {_number(scaling)}"
    return _cell(text)


def _scalings(outcome: Outcome) -> tuple[str | None, str | None]:
    return tuple(None if v is None else _number(v) for v in (outcome.velocity_scaling, outcome.acceleration_scaling))  # type: ignore[return-value]


def _vector(values: Any, opening: str = "[", closing: str = "]") -> str:
    return opening + ", ".join(_number(v) for v in values) + closing


def _number(value: Any) -> str:
    if type(value) not in (int, float):
        raise ValueError(value)
    text = f"{float(value):.3f}"
    return "0.000" if text == "-0.000" else text


def _codes(codes: Sequence[str]) -> str:
    return ", ".join(codes) if codes else "—"


def _outcome_text(outcome: Outcome) -> str:
    text = outcome.status + (f" ({', '.join(outcome.codes)})" if outcome.codes else "")
    return text + (" †" if outcome.detour else "")


def _change_text(change: str | None) -> str:
    return {"newly_rejected": "**newly rejected**", "newly_allowed": "newly allowed",
            "newly_needs_approval": "newly needs approval", "unchanged": "unchanged"}.get(change or "", "—")


def _cell(text: str) -> str:
    """Text safe inside a markdown table cell: one line, no pipes."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _outcome_data(outcome: Outcome | None) -> dict[str, Any] | None:
    if outcome is None:
        return None
    return {"status": outcome.status, "codes": list(outcome.codes), "detour": outcome.detour,
            "velocity_scaling": _scalings(outcome)[0], "acceleration_scaling": _scalings(outcome)[1]}


def _row_data(row: PlanRow) -> dict[str, Any]:
    call = row.call
    return {"line": call.line, "seq": call.seq, "tool": call.tool, "plan_id": call.plan_id,
            "request": describe_request(call), "recorded": _outcome_data(call.recorded),
            "recorded_refusal": call.refusal, "original": _outcome_data(row.original),
            "candidate": _outcome_data(row.candidate), "change": row.change, "codes_added": list(row.codes_added),
            "codes_removed": list(row.codes_removed), "speed_changed": row.speed_changed, "replayable": row.replayed,
            "reason": row.reason}


def _execution_data(run: Execution, row: PlanRow) -> dict[str, Any]:
    return {"line": run.line, "seq": run.seq, "plan_id": run.plan_id, "status": run.status, "plan_line": row.call.line,
            "request": describe_request(row.call), "original": _outcome_data(row.original),
            "candidate": _outcome_data(row.candidate), "codes_added": list(row.codes_added)}
