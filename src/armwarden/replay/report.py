"""The replay report's data: per plan, the original outcome against the candidate's, what that
means, and the JSON form (`markdown` renders the same data for people).

Each replayed plan falls in exactly one class, by how its status moved on the scale
ok < needs_approval < rejected:

- ``newly_rejected``: the candidate rejects it and the original did not;
- ``newly_needs_approval``: ok before, a human must approve it now;
- ``newly_allowed``: the candidate is less strict (rejected → needs_approval or ok,
  needs_approval → ok);
- ``unchanged``: same status (the violation codes may still differ; the report shows which).

Executions that moved the arm and whose plan the candidate rejects come first in both forms: those
are the motions the candidate policy would have stopped. A speed cap never rejects a plan (a
scaling above the cap is clamped to it), so what a changed speed cap does shows as speed changes:
the plans whose velocity or acceleration scaling, after the caps, differs. Both forms are
deterministic: log order, sorted codes, fixed float formatting, nothing about the run itself.
"""

from __future__ import annotations

import json
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
        return scalings_text(self.original) != scalings_text(self.candidate) and None not in (
            *scalings_text(self.original), *scalings_text(self.candidate))

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
    return table_cell(text)


def scalings_text(outcome: Outcome) -> tuple[str | None, str | None]:
    return tuple(None if v is None else _number(v) for v in (outcome.velocity_scaling, outcome.acceleration_scaling))  # type: ignore[return-value]


def _vector(values: Any, opening: str = "[", closing: str = "]") -> str:
    return opening + ", ".join(_number(v) for v in values) + closing


def _number(value: Any) -> str:
    if type(value) not in (int, float):
        raise ValueError(value)
    text = f"{float(value):.3f}"
    return "0.000" if text == "-0.000" else text


def table_cell(text: str) -> str:
    """Text safe inside a markdown table cell: one line, no pipes."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _outcome_data(outcome: Outcome | None) -> dict[str, Any] | None:
    if outcome is None:
        return None
    return {"status": outcome.status, "codes": list(outcome.codes), "detour": outcome.detour,
            "velocity_scaling": scalings_text(outcome)[0], "acceleration_scaling": scalings_text(outcome)[1]}


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
