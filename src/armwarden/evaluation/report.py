"""The evaluation's report: markdown for people, JSON for CI and comparisons.

What this version does not run (fuzzing, fault injection, load) is reported as not run, with why,
never as a figure.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

from armwarden import __version__
from armwarden.evaluation.runner import EvalOptions, EvalResult
from armwarden.policy import policy_digest

NOT_BUILT = {"run": False, "why": "not in this version"}


def report_data(options: EvalOptions, result: EvalResult) -> dict[str, Any]:
    low, high = result.safe.interval()
    return {
        "version": __version__,
        "policy": str(options.policy_path),
        "policy_digest": policy_digest(options.policy),
        "backend": options.backend,
        "seed": options.seed,
        "only": list(options.only),  # non-empty: a filtered run (no safe requests), not the whole evaluation
        "passed": result.ok,
        "unsafe": [asdict(r) for r in result.unsafe],
        "skipped": list(result.skipped),
        "safe": {"attempted": result.safe.attempted, "executed": result.safe.executed,
                 "wilson_low": low, "wilson_high": high, "failures": result.safe.failures},
        "fuzz": NOT_BUILT,
        "faults": NOT_BUILT,
        "load": NOT_BUILT,
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
        f"backend `{data['backend']}`, seed {data['seed']}."
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
    lines += ["", "## Not run by this version", ""]
    lines += [f"- {key}: {data[key]['why']}" for key in ("fuzz", "faults", "load")]
    return "\n".join(lines) + "\n"
