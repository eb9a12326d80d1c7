"""`armwarden eval` end to end: the real command, which starts the real daemon as a subprocess.

The evaluation proves something only if a weaker Guard fails it: the mutant tests take edits from
scripts/mutation.py (one check removed each), apply them to a copy of `src`, and run the command
with PYTHONPATH on that copy (the daemon subprocess inherits it): each must make a scenario fail.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from armwarden.evaluation.stats import wilson_interval
from tests.helpers import REPO, SRC

#: scenarios that execute one legitimate plan before the refusal they test
ALLOWED = {"an executed plan cannot be executed again, even from its start state": 2,
           "a plan whose start state has moved is refused": 1,
           "a gripper call over its rate limit (1/min) is refused": 1}
#: a whole --quick run: two daemon start-ups and ~80 calls on a loaded 2-core machine
EVAL_TIMEOUT_S = 900


def _run_eval(tmp_path: Path, src: Path) -> tuple[int, dict, str]:
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 20\n", encoding="utf-8")
    out = tmp_path / "eval.json"
    env = {**os.environ, "PYTHONPATH": f"{src}:{REPO}"}
    env.pop("ARMWARDEN_AUDIT_KEY", None)
    done = subprocess.run([sys.executable, "-m", "armwarden.cli", "eval", "--quick", "--backend-config", str(config),
                           "--json", str(out), "--report", str(tmp_path / "eval.md")],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=EVAL_TIMEOUT_S)
    data = json.loads(out.read_text(encoding="utf-8")) if out.exists() else {}
    return done.returncode, data, done.stderr


@pytest.mark.parametrize(("successes", "trials", "low", "high"), [
    (0, 10, 0.0, 0.2775),
    (10, 10, 0.7225, 1.0),
    (5, 10, 0.2366, 0.7634),
    (95, 100, 0.8882, 0.9785),
])
def test_wilson_interval_matches_published_values(successes, trials, low, high) -> None:
    assert wilson_interval(successes, trials) == pytest.approx((low, high), abs=1e-4)


def test_wilson_interval_of_no_trials_says_nothing() -> None:
    assert wilson_interval(0, 0) == (0.0, 1.0)


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
def test_quick_eval_on_fake_passes_every_scenario_with_no_actuation(tmp_path) -> None:
    code, data, stderr = _run_eval(tmp_path, SRC)
    assert code == 0, stderr[-3000:]
    assert len(data["unsafe"]) >= 60
    failed = [r for r in data["unsafe"] if not r["passed"]]
    assert failed == []
    assert all(r["actuations"] == ALLOWED.get(r["name"], 0) for r in data["unsafe"]), data["unsafe"]
    assert data["safe"]["attempted"] == data["safe"]["executed"] == 10
    assert 0 < data["safe"]["wilson_low"] < 1 and data["safe"]["wilson_high"] == pytest.approx(1.0)
    for key in ("fuzz", "faults", "load"):
        assert data[key] == {"run": False, "why": "not in this version"}
    assert data["backend"] == "fake" and data["policy_digest"] and data["version"]
    assert "PASSED" in (tmp_path / "eval.md").read_text(encoding="utf-8")


def _mutation_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("armwarden_mutation_script_eval", REPO / "scripts" / "mutation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.timeout(EVAL_TIMEOUT_S + 60)
@pytest.mark.parametrize(("mutant", "caught_by"), [
    ("plans-single-use", "an executed plan cannot be executed again, even from its start state"),
    ("plans-ttl", "a plan past its TTL (shortened to 2 s) is refused"),
    # the probe link is chosen by the (mutated) envelope's start-up check: any link's scenario
    ("envelope-keep-out", "ending inside a keep-out zone (TCP clear) is refused"),
])
def test_a_weakened_guard_fails_the_eval(tmp_path, mutant, caught_by) -> None:
    script = _mutation_script()
    (found,) = [m for m in script.MUTANTS if m.name == mutant]
    src = tmp_path / "src"
    shutil.copytree(SRC, src, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    script.apply(found, src)
    code, data, stderr = _run_eval(tmp_path, src)
    assert code == 1, stderr[-3000:]
    failed = {r["name"] for r in data["unsafe"] if not r["passed"]}
    assert any(name.endswith(caught_by) for name in failed), failed
