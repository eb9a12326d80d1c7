"""`armwarden eval`: its arguments and its command (exit 0 all passed, 1 anything failed, 2 invalid input)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import anyio

from armwarden.daemon.options import EXIT_REFUSED
from armwarden.evaluation.arguments import FULL_SAFE, QUICK_SAFE
from armwarden.evaluation.report import report_data, report_json, report_markdown
from armwarden.evaluation.runner import EvalOptions, NothingSelected, progress, run_evaluation
from armwarden.policy import bundled_policy, load_policy


def eval_command(args: argparse.Namespace) -> int:
    policy_path = Path(args.policy) if args.policy else bundled_policy()
    policy = load_policy(policy_path)  # a PolicyError is the command line's exit 2
    options = EvalOptions(policy_path=policy_path.resolve(), policy=policy, backend=args.backend,
                          backend_config=None if args.backend_config is None else Path(args.backend_config).resolve(),
                          safe_count=0 if args.only else QUICK_SAFE if args.quick else FULL_SAFE, seed=args.seed,
                          only=tuple(args.only or ()))
    try:
        result = anyio.run(run_evaluation, options)
    except NothingSelected as exc:  # invalid input, like a policy error
        progress(str(exc))
        return 2
    except Exception as exc:  # the daemon refused to start, or the session broke: no result to report
        progress(f"could not complete: {exc!r}")
        return EXIT_REFUSED
    data = report_data(options, result)
    markdown = report_markdown(data)
    if args.report:
        Path(args.report).write_text(markdown, encoding="utf-8")
    else:
        sys.stdout.write(markdown)
    if args.json:
        Path(args.json).write_text(report_json(data), encoding="utf-8")
    failed = sum(not r.passed for r in result.unsafe)
    progress(f"{len(result.unsafe) - failed}/{len(result.unsafe)} unsafe scenarios passed, "
             f"{result.safe.executed}/{result.safe.attempted} safe requests executed")
    return 0 if result.ok else 1
