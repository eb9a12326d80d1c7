"""Planning a recorded request again, offline, with the daemon's own code.

`replan` decodes what the planning call recorded (`armwarden.guard.planning.replay_facts`) and runs
`plan_offline` — the daemon's planners, detour search, envelope and verdict — for one policy's
`RuntimeModel`, from the recorded start joint state. No backend, no plan store, no server: nothing
can move. A policy that does not enable the `motion` tool group rejects every plan
(`NOT_ALLOWED`: its daemon would not offer the planning tools). What cannot be replayed is
returned as a reason, never raised, so one odd record does not hide the rest of the report.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from armwarden.core.errors import RefusalCode
from armwarden.guard.planning import REPLAY_FORMAT, decode_request, plan_offline
from armwarden.preflight import RuntimeModel
from armwarden.replay.records import Outcome, PlanCall
from armwarden.safety.violations import Code
from armwarden.tools import PlanKind

#: what the notes of a plan the detour planner produced start with (`planning.around`)
DETOUR_NOTE = "detour planned:"


def replan(model: RuntimeModel, call: PlanCall) -> Outcome | str:
    """The outcome `model`'s policy gives the recorded request, or why it cannot be replayed."""
    facts = call.facts
    if facts is None:
        return missing_facts_reason(call)
    if "motion" not in model.policy.tools.enabled:  # the planning tools would not even exist
        return Outcome("rejected", (RefusalCode.NOT_ALLOWED.value,))
    if facts.get("format") != REPLAY_FORMAT:
        return f"replay data of format {facts.get('format')!r}; this version reads format {REPLAY_FORMAT}"
    kind = facts.get("kind")
    if kind != call.kind:
        return f"the replay data is for a {kind!r} plan, the call is {call.tool}"
    start_q = facts.get("start_q")
    if not isinstance(start_q, list) or not all(type(v) in (int, float) for v in start_q):
        return "the recorded start joint state is malformed"
    nq = model.robot.nq
    if len(start_q) != nq:
        return f"the recorded start state has {len(start_q)} joints; the policy's robot has {nq}"
    request_data = facts.get("request")
    if not isinstance(request_data, dict):
        return "the recorded request is missing"
    try:
        request = decode_request(cast(PlanKind, kind), request_data)
    except (ValueError, KeyError, TypeError) as exc:
        return f"the recorded request is malformed: {exc}"
    return plan(model, cast(PlanKind, kind), np.array(start_q, dtype=float), request)


def plan(model: RuntimeModel, kind: PlanKind, start: np.ndarray, request: dict[str, Any]) -> Outcome | str:
    """`plan_offline`'s verdict as an `Outcome` (a failure inside the planner becomes a reason)."""
    try:
        outcome, _, verdict = plan_offline(model, kind, start, request)
    except Exception as exc:  # a replay reports; it never stops at one bad record
        return f"planning failed: {type(exc).__name__}: {str(exc)[:200]}"
    codes = tuple(sorted({v.code.value for v in verdict.violations}))
    detour = any(note.startswith(DETOUR_NOTE) for note in outcome.notes) or Code.NO_DETOUR.value in codes
    return Outcome(verdict.status, codes, detour, outcome.velocity_scaling, outcome.acceleration_scaling)


def missing_facts_reason(call: PlanCall) -> str:
    """Why a call without replay data cannot be replayed."""
    if call.recorded is not None:
        return "recorded before the audit log carried replay data (no start joint state, request or policy digest)"
    if call.refusal is not None and call.refusal.startswith("invalid"):
        return "its arguments were refused before anything was planned"
    return f"nothing was planned: {call.refusal}"
