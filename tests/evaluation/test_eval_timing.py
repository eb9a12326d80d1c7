"""The evaluation's timing overrides: on every backend the wrench timeout goes to the policy's
ceiling, so a loaded host's stall is not reported as failed scenarios."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import pytest

from armwarden.evaluation import runner
from armwarden.evaluation.runner import EVAL_WRENCH_TIMEOUT_S, EvalOptions, run_evaluation
from armwarden.policy import bundled_policy, load_policy


def _overrides(backend: str, monkeypatch: pytest.MonkeyPatch) -> dict[str, dict[str, Any]]:
    seen: dict[str, dict[str, Any]] = {}

    async def with_daemon(options: Any, directory: Path, name: str, overrides: dict[str, Any], *rest: Any) -> None:
        seen[name] = overrides

    monkeypatch.setattr(runner, "_with_daemon", with_daemon)
    path = bundled_policy()
    options = EvalOptions(path, load_policy(path), backend, None, safe_count=0, seed=0)
    anyio.run(run_evaluation, options)
    return seen


@pytest.mark.parametrize("backend", ["fake", "mujoco", "can"])
def test_every_daemon_gets_the_wrench_timeout_ceiling(backend: str, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = _overrides(backend, monkeypatch)
    assert set(seen) == {"main", "no_elicitation", "short_ttl"}
    assert all(o["force.wrench_timeout_s"] == EVAL_WRENCH_TIMEOUT_S for o in seen.values())
