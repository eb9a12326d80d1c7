"""The test harness builds each backend through the `build_for_tests` of its package's `testing`
module (docs/add-a-backend.md): no list of backend names in the harness, so a third party's
backend gets harness support by shipping one."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from armwarden.backends import BACKENDS
from armwarden.policy import bundled_policy, load_policy
from tests.backends.minimal_backend import MinimalBackend
from tests.server import harness

ROOT = Path(__file__).resolve().parents[2]

#: a third party's backend package: the registered module and its testing module beside it
THIRD_PARTY_BACKEND = '''
from pydantic import BaseModel, ConfigDict

from tests.backends.minimal_backend import MinimalBackend


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def create_backend(robot, policy, config):
    return MinimalBackend(robot.joint_names, policy.robot.home_joint_positions,
                          start_tolerance_rad=policy.motion.start_tolerance_rad)
'''
THIRD_PARTY_TESTING = '''
from tests.backends.minimal_backend import MinimalBackend


def build_for_tests(policy, robot, *, speedup, options):
    backend = MinimalBackend(robot.joint_names, policy.robot.home_joint_positions,
                             start_tolerance_rad=policy.motion.start_tolerance_rad, speedup=speedup)
    backend.built_by = ("thirdarm testing", dict(options))
    return backend
'''


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_every_built_in_backend_has_a_testing_module_the_harness_finds(name: str) -> None:
    module = harness.testing_module(name)
    assert module.endswith(".testing") and module.startswith("armwarden.backends.")
    assert (ROOT / "src" / Path(*module.split("."))).with_suffix(".py").is_file()


def test_the_harness_and_the_testing_modules_import_no_rclpy_and_no_python_can() -> None:
    program = textwrap.dedent("""
        import importlib, json, sys
        from tests.server import harness
        for name in ("fake", "mujoco", "can", "ros2"):
            module = importlib.import_module(harness.testing_module(name))
            assert callable(module.build_for_tests), name
        print(json.dumps(sorted(m for m in ("rclpy", "can", "mujoco") if m in sys.modules)))
    """)
    run = subprocess.run([sys.executable, "-c", program], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []


def test_a_third_party_backend_is_built_by_the_testing_module_beside_it(tmp_path, monkeypatch) -> None:
    package = tmp_path / "thirdarm"
    package.mkdir()
    (package / "__init__.py").write_text("", encoding="utf-8")
    (package / "backend.py").write_text(textwrap.dedent(THIRD_PARTY_BACKEND), encoding="utf-8")
    (package / "testing.py").write_text(textwrap.dedent(THIRD_PARTY_TESTING), encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(harness, "registered_backends", lambda: {"thirdarm": "thirdarm.backend"})

    backend = harness._backend("thirdarm", load_policy(bundled_policy("fr3")), {"option": 1})

    assert isinstance(backend, MinimalBackend)
    assert backend.built_by == ("thirdarm testing", {"option": 1})  # type: ignore[attr-defined]
    assert backend.speedup == 1.0  # the harness's speedup for a backend it has none for


def test_an_unknown_harness_backend_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="unknown harness backend 'nosucharm'"):
        harness._backend("nosucharm", load_policy(bundled_policy("fr3")), {})
