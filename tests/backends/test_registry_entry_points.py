"""A backend from another package, registered as an entry point, is served like a built-in one; it
cannot take a built-in's name."""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from armwarden import backends
from armwarden.core.errors import BackendUnavailable
from armwarden.policy import bundled_policy, load_policy
from armwarden.robot import build_robot
from tests.backends.minimal_backend import MinimalBackend

#: a third party's backend module: the minimal backend with a strict Config of one option
PLUGIN_MODULE = '''
from pydantic import BaseModel, ConfigDict, Field

from tests.backends.minimal_backend import MinimalBackend


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    speedup: float = Field(default=1.0, gt=0)


def create_backend(robot, policy, config):
    return MinimalBackend(robot.joint_names, policy.robot.home_joint_positions,
                          start_tolerance_rad=policy.motion.start_tolerance_rad, speedup=config.speedup)
'''


@pytest.fixture
def installed_plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A package on sys.path whose dist-info registers `thirdarm` and tries to take `fake`."""
    (tmp_path / "thirdarm_backend.py").write_text(textwrap.dedent(PLUGIN_MODULE), encoding="utf-8")
    dist = tmp_path / "thirdarm-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdarm\nVersion: 1.0\n", encoding="utf-8")
    (dist / "entry_points.txt").write_text(
        "[armwarden.backends]\nthirdarm = thirdarm_backend\nfake = thirdarm_backend\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    backends._entry_point_backends.cache_clear()
    yield "thirdarm"
    sys.modules.pop("thirdarm_backend", None)
    monkeypatch.undo()
    backends._entry_point_backends.cache_clear()


def test_an_entry_point_backend_is_named_and_built_like_a_built_in_one(installed_plugin: str) -> None:
    policy = load_policy(bundled_policy("fr3"))
    assert installed_plugin in backends.backend_names()
    backend = backends.create_backend(installed_plugin, build_robot(policy), policy, {"speedup": 2.0})
    assert isinstance(backend, MinimalBackend)


def test_an_entry_point_cannot_take_a_built_in_backends_name(installed_plugin: str, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level("WARNING", logger="armwarden.backends"):
        backends._entry_point_backends.cache_clear()
        names = backends.registered_backends()
    assert names["fake"] == backends.BACKENDS["fake"]
    assert "ignoring the entry point fake = thirdarm_backend" in caplog.text


def test_an_entry_point_backend_config_is_as_strict_as_a_built_in_ones(installed_plugin: str) -> None:
    with pytest.raises(Exception, match="speedup"):
        backends.parse_backend_config(installed_plugin, {"speedup": -1.0})


def test_a_module_without_config_and_factory_is_refused_naming_what_is_missing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "hollow_backend.py").write_text("VALUE = 1\n", encoding="utf-8")
    dist = tmp_path / "hollow-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: hollow\nVersion: 1.0\n", encoding="utf-8")
    (dist / "entry_points.txt").write_text("[armwarden.backends]\nhollow = hollow_backend\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    backends._entry_point_backends.cache_clear()
    try:
        with pytest.raises(BackendUnavailable, match="defines no `Config` model and `create_backend` function"):
            backends.backend_module("hollow")
    finally:
        sys.modules.pop("hollow_backend", None)
        monkeypatch.undo()
        backends._entry_point_backends.cache_clear()
