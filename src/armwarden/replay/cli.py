"""`armwarden audit replay LOG --policy CANDIDATE.yaml [--original ORIGINAL.yaml] [--json FILE] [--allow-broken]`.

Exit status: 0 the report was written (whatever it says); 1 the log is unreadable or its chain is
broken (without --allow-broken); 2 a policy is invalid.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from armwarden.core.errors import PolicyError
from armwarden.policy import load_policy, policy_digest
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.replay.engine import replan
from armwarden.replay.markdown import render_markdown
from armwarden.replay.records import BrokenLog, TrustedLog, read_trusted
from armwarden.replay.report import PlanRow, PolicyRef, ReplayReport

EXIT_OK, EXIT_FAILED, EXIT_REFUSED = 0, 1, 2


def replay_log(log: TrustedLog, candidate: RuntimeModel, candidate_name: str,
               original: RuntimeModel | None = None, original_name: str | None = None) -> ReplayReport:
    """Re-plan every plan call of `log` under `candidate` (and under `original` when given; else
    the recorded outcome is the original)."""
    rows = []
    for call in log.plan_calls():
        planned = replan(candidate, call)
        if original is not None:
            before = replan(original, call)
        else:
            before = call.recorded if call.recorded is not None else None
        if isinstance(planned, str):
            rows.append(PlanRow(call, None if isinstance(before, str) else before, None, planned))
        elif isinstance(before, str):
            rows.append(PlanRow(call, None, planned, before))
        elif before is None:
            rows.append(PlanRow(call, None, planned, f"no recorded outcome to compare with: {call.refusal}"))
        else:
            rows.append(PlanRow(call, before, planned))
    original_ref = None if original is None else PolicyRef(original_name or "original", policy_digest(original.policy))
    return ReplayReport(log, PolicyRef(candidate_name, policy_digest(candidate.policy)), original_ref, tuple(rows),
                        tuple(log.executions()), tuple(log.policy_digests()))


def _model(path: str) -> RuntimeModel:
    return load_runtime_model(load_policy(path), path)


def replay_command(log_path: str | os.PathLike[str], policy_path: str, *, original: str | None = None,
                   json_path: str | None = None, allow_broken: bool = False, key: bytes | None = None) -> int:
    """Verify, replay and print the markdown report (stdout); see the module docstring for exit codes."""
    try:
        candidate = _model(policy_path)
        before = _model(original) if original is not None else None
    except PolicyError as exc:
        print(f"INVALID: {exc.source} ({len(exc.errors)} error{'s' if len(exc.errors) != 1 else ''})", file=sys.stderr)
        for yaml_path, message in exc.errors:
            print(f"  {yaml_path}: {message}", file=sys.stderr)
        return EXIT_REFUSED
    try:
        log = read_trusted(log_path, key, allow_broken=allow_broken)
    except BrokenLog as exc:
        print(f"FAILED: {exc}", file=sys.stderr)
        return EXIT_FAILED
    report = replay_log(log, candidate, Path(policy_path).name, before, None if original is None else Path(original).name)
    sys.stdout.write(render_markdown(report))
    if json_path is not None:
        try:
            Path(json_path).write_text(report.to_json(), encoding="utf-8")
        except OSError as exc:
            print(f"FAILED: cannot write {json_path}: {exc}", file=sys.stderr)
            return EXIT_FAILED
    return EXIT_OK
