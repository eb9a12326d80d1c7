"""The evaluation's timing overrides: on a real-time backend (physics or emulator thread in the
daemon) the wrench timeout goes to the policy's ceiling, so a loaded host's stall is not reported
as failed scenarios; the fake keeps the policy's own."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import pytest

from armwarden.evaluation import runner
from armwarden.evaluation.runner import REALTIME_WRENCH_TIMEOUT_S, EvalOptions, run_evaluation
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


@pytest.mark.parametrize("backend", ["mujoco", "can"])
def test_a_realtime_backend_gets_the_wrench_timeout_ceiling_in_both_daemons(
        backend: str, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = _overrides(backend, monkeypatch)
    assert set(seen) == {"main", "no_elicitation"}
    assert all(o["force.wrench_timeout_s"] == REALTIME_WRENCH_TIMEOUT_S for o in seen.values())


def test_the_fake_keeps_the_policys_wrench_timeout(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = _overrides("fake", monkeypatch)
    assert all("force.wrench_timeout_s" not in o for o in seen.values())
