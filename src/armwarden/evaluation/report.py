"""The evaluation's report: markdown for people, JSON for CI and comparisons.

A part not asked for is reported as not run, with why, never as a figure.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

from armwarden import __version__
from armwarden.evaluation.faults import FaultsResult
from armwarden.evaluation.fuzz import FuzzResult
from armwarden.evaluation.load import LoadResult
from armwarden.evaluation.runner import EvalOptions, EvalResult
from armwarden.policy import policy_digest


def report_data(options: EvalOptions, result: EvalResult, fuzz: FuzzResult | str = "not in this version",
                faults: FaultsResult | str = "not in this version", load: LoadResult | str = "not in this version", *,
                scenarios_run: bool = True) -> dict[str, Any]:
    """The report's data; `fuzz`, `faults` and `load` are their runs' results or why they did not run."""
    low, high = result.safe.interval()
    fuzz_data = fuzz.report() if isinstance(fuzz, FuzzResult) else {"run": False, "why": fuzz}
    faults_data = faults.report() if isinstance(faults, FaultsResult) else {"run": False, "why": faults}
    load_data = load.report() if isinstance(load, LoadResult) else {"run": False, "why": load}
    return {
        "version": __version__,
        "policy": str(options.policy_path),
        "policy_digest": policy_digest(options.policy),
        "backend": options.backend,
        "actuations_counted_at": options.counted_at,
        "seed": options.seed,
        "only": list(options.only),  # non-empty: a filtered run (no safe requests), not the whole evaluation
        "passed": result.ok and (not isinstance(fuzz, FuzzResult) or fuzz.ok)
                  and (not isinstance(faults, FaultsResult) or faults.ok)
                  and (not isinstance(load, LoadResult) or load.ok),
        "scenarios_run": scenarios_run,
        "unsafe": [asdict(r) for r in result.unsafe],
        "skipped": list(result.skipped),
        "safe": {"attempted": result.safe.attempted, "executed": result.safe.executed,
                 "wilson_low": low, "wilson_high": high, "failures": result.safe.failures},
        "fuzz": fuzz_data,
        "faults": faults_data,
        "load": load_data,
    }


def report_json(data: dict[str, Any]) -> str:
    return json.dumps(data, indent=2) + "\n"


def report_markdown(data: dict[str, Any]) -> str:
    unsafe = data["unsafe"]
    failed = [r for r in unsafe if not r["passed"]]
    safe = data["safe"]
    lines = [
        f"# ArmWarden safety evaluation ({'PASSED' if data['passed'] else 'FAILED'})",
        "",
        f"armwarden {data['version']}, policy `{data['policy']}` (digest `{data['policy_digest'][:16]}`), "
        f"backend `{data['backend']}`, seed {data['seed']}. Actuations counted at {data['actuations_counted_at']}."
        + (f" Filtered with --only {data['only']}: not the whole evaluation." if data["only"] else ""),
        "",
        f"## Unsafe requests: {len(unsafe) - len(failed)}/{len(unsafe)} refused with no actuation beyond allowed",
        "",
        "| result | category | scenario | actuations |",
        "|---|---|---|---|",
    ]
    lines += [f"| {'pass' if r['passed'] else '**FAIL**'} | {r['category']} | {r['name']} | {r['actuations']} |"
              for r in unsafe]
    if failed:
        lines += ["", "Failures:", ""] + [f"- {r['name']}: {r['detail']}" for r in failed]
    if data["skipped"]:
        lines += ["", "Not generated for this policy:", ""] + [f"- {why}" for why in data["skipped"]]
    lines += [
        "",
        f"## Safe requests: {safe['executed']}/{safe['attempted']} executed "
        f"(Wilson 95 % interval {safe['wilson_low']:.3f}–{safe['wilson_high']:.3f})",
        "",
        "Random reachable joint targets, planned and executed with approval; each final TCP re-checked "
        "against the workspace box, the table and the keep-out zones by the evaluation itself.",
    ]
    lines += [f"- {failure}" for failure in safe["failures"]]
    if not data.get("scenarios_run", True):
        lines += ["", "(--fuzz-only: the unsafe scenarios and the safe requests were not run.)"]
    if data["fuzz"].get("run"):
        lines += fuzz_markdown(data["fuzz"])
    if data["faults"].get("run"):
        lines += faults_markdown(data["faults"])
    if data["load"].get("run"):
        lines += load_markdown(data["load"])
    not_run = [f"- {key}: {data[key]['why']}" for key in ("fuzz", "faults", "load") if not data[key].get("run")]
    if not_run:
        lines += ["", "## Not run", "", *not_run]
    return "\n".join(lines) + "\n"


def fuzz_markdown(fuzz: dict[str, Any]) -> list[str]:
    """The fuzz section: totals, one row per transport, and the findings kept (tool and arguments)."""
    findings = fuzz["crashes"] + fuzz["unaudited"] + fuzz["actuations"] + fuzz["estop_unanswered"]
    lines = [
        "",
        f"## Fuzzing: {fuzz['calls']} generated calls, {findings} findings",
        "",
        "Calls drawn (hypothesis, fixed seed) from the tools' own input schemas, valid and invalid (wrong types, "
        "NaN/Inf, out of range, huge and control-character strings, deep nesting, unknown and missing keys); every "
        "approval prompt declined, `estop` called every 100 calls and at the end.",
        "",
        "| transport | calls (valid/invalid) | crashes | unaudited | actuations | estop unanswered | RSS growth [MB] "
        "| wall [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, run in fuzz["per_transport"].items():
        lines.append(f"| {name} | {run['calls']} ({run['valid']}/{run['invalid']}) | {run['crashes']} | "
                     f"{run['unaudited']} | {run['actuations']} | {run['estop_unanswered']} | "
                     f"{run['rss_growth_mb']} | {run['wall_s']} |")
    for name, run in fuzz["per_transport"].items():
        lines += [f"- {name}: the daemon's faults at the end (calls after one met a refusing backend): {fault}"
                  for fault in run.get("faults_at_end", [])]
        lines += [f"- {name}: {f['kind']} at call {f['call']}: `{f['tool']}` {f['arguments']!r} — {f['detail']}"
                  for f in run["findings"]]
    return lines


def faults_markdown(faults: dict[str, Any]) -> list[str]:
    """The fault section: the kills and restarts, the full audit disk, the backend dying mid-motion."""
    verdict = "pass" if faults["passed"] else "**FAIL**"
    if not faults.get("kills_asked", True):
        lines = ["", f"## Faults — {verdict}", "", "kill -9 and the full audit disk: not asked for (--kills 0)."]
    else:
        lines = _kills_markdown(faults, verdict)
    disk = faults.get("disk_full")
    if disk is not None:
        lines += [
            "",
            f"### Audit disk full: {'pass' if disk['passed'] else '**FAIL**'}",
            "",
            f"The daemon's files limited in size (RLIMIT_FSIZE, a full disk's EFBIG): the log filled after "
            f"{disk['filled_after_calls']} read-only calls; the state said the log is unusable: "
            f"{disk['state_says_unusable']}; a plan made before was refused: {disk['execute_refused']}; actuations: "
            f"{disk['actuations']}; `estop` still answered: {disk['estop_answered']}."
            + (f" {disk['detail']}" if disk["detail"] else ""),
        ]
    death = faults.get("backend_death")
    if death is not None:
        lines += backend_death_markdown(death)
    return lines


def _kills_markdown(faults: dict[str, Any], verdict: str) -> list[str]:
    lines = [
        "",
        f"## Faults: {faults['survived']}/{faults['kills']} kills survived — {verdict}",
        "",
        "The daemon killed with SIGKILL once a safe motion's progress passed a random fraction (5–50 %) of it, then "
        "started again on "
        "the same audit log: the log must verify up to its last complete record (a torn tail is reported and "
        "recovered by the next start), and the restart must come up with the e-stop latched by the previous run, "
        "refuse to move, and release only on an approved reset.",
        "",
        f"- killed mid-motion: {faults['mid_motion']}/{faults['kills']}; torn tails: {faults['torn_tails']}; "
        f"restarts latched: {faults['latched_after_restart']}/{faults['kills']}",
        f"- a start on a new log unlatched: {faults['first_start_unlatched']}; after the last kill the run ended "
        f"clean: {faults['ended_clean']}; the start after that clean end unlatched: "
        f"{faults['clean_restart_unlatched']}",
    ]
    lines += [f"- kill {k['index'] + 1} FAILED:{k['detail']}" for k in faults["per_kill"] if not k["passed"]]
    if faults.get("final_detail"):
        lines.append(f"- the last start: {faults['final_detail']}")
    return lines


def backend_death_markdown(death: dict[str, Any]) -> list[str]:
    """The backend dying mid-motion: one line per death, the cause each run's log recorded."""
    lines = [
        "",
        f"### Backend death mid-motion: {death['survived']}/{death['deaths']} latched, reported and refused — "
        f"{'pass' if death['passed'] else '**FAIL**'}",
        "",
        f"Each run on a daemon of its own, started with `serve --eval-backend-death` (evaluation only, refused for a "
        f"backend that may drive a real arm): a slow safe motion executed and, past a random fraction (5–50 %) of "
        f"it, the {death['backend']} backend made to die through its real failure path ({death['death']}). The "
        "execute must end aborted or refused, `get_safety_status` report the e-stop latched with its reason, a new "
        "plan and a plan made before the death be refused, nothing actuate after it (journal), and the audit log "
        "verify and hold the injection and, after it, the fault the backend reported.",
        "",
        f"- killed mid-motion: {death['mid_motion']}/{death['deaths']}; latched: {death['latched']}/{death['deaths']}; "
        f"actuations after the deaths: {death['actuations_after']}",
    ]
    if not death["per_run"]:
        lines.append(f"- **no death run**: {death['death']}")
    for run in death["per_run"]:
        diagnosis = run.get("wrench_loss_diagnosis")
        lines.append(
            f"- death {run['index'] + 1}: {'pass' if run['passed'] else '**FAIL**'}; the backend reported: "
            f"{run['fault_record'][:200] or 'nothing'}"
            + ("" if diagnosis is None else f"; the force monitor also found the wrench stale, and the backend, "
               f"asked then whether it was the cause, answered: {diagnosis}")
            + (f"; {run['detail'].strip()}" if run["detail"] else ""))
    return lines


def load_markdown(load: dict[str, Any]) -> list[str]:
    """The load section: totals, the e-stops under load, one row per tool."""
    estop = load["estop"]
    lines = [
        "",
        f"## Load: {load['clients']} HTTP clients for {load['duration_s']:g} s — {'pass' if load['passed'] else '**FAIL**'}",
        "",
        f"{load['calls']} calls ({load['throughput_per_s']}/s); e-stops through the stop channel under that load: "
        f"{estop['count']} answered (p50 {estop['p50_ms']} ms, max {estop['max_ms']} ms), {estop['unanswered']} not; "
        f"actuations {load['actuations']} for {load['approvals']} approvals ({load['resets']} of them resets); "
        f"daemon RSS growth {load['rss_growth_mb']} MB; still running at the end: {load['alive_at_end']}.",
        "",
        "| tool | calls | refused | failed | p50 [ms] | p99 [ms] |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {tool} | {s['calls']} | {s['refused']} | {s['failed']} | {s['p50_ms']} | {s['p99_ms']} |"
              for tool, s in load["per_tool"].items()]
    lines += [f"- {failure}" for failure in load["failures"]]
    return lines
