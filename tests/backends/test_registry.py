"""The backend registry: the backends and what each needs, strict backend configs, and what the CLI says."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from armwarden import backends
from armwarden.backends import backend_names, create_backend, load_backend_config
from armwarden.backends.fake import Config
from armwarden.backends.fake.backend import FakeBackend
from armwarden.cli import main
from armwarden.core.errors import BackendUnavailable, ConfigurationError
from armwarden.policy import Policy
from armwarden.robot import RobotModel

REPO = Path(__file__).resolve().parents[2]


def test_the_cli_choices_are_the_backends() -> None:
    assert backend_names() == ("fake", "mujoco", "can", "ros2")
    assert list(backends.BACKENDS) == ["fake", "mujoco", "can", "ros2"]


def test_serve_help_names_every_backend_what_it_needs_and_what_a_missing_one_does(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("COLUMNS", "400")  # wide: no word of the help is cut at a hyphen
    with pytest.raises(SystemExit):
        main(["serve", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    start = help_text.index("robot backend:")
    backend_help = help_text[start:help_text.index("--backend-config BACKEND_CONFIG", start)]
    assert "not built yet" not in help_text
    for name in backend_names():
        assert f"{name} (" in backend_help, name
    assert "armwarden[mujoco]" in backend_help and "armwarden[can]" in backend_help and "rclpy" in backend_help
    assert "missing" in backend_help and "says so" in backend_help


def test_create_backend_builds_the_fake_for_the_policy_robot(fr3_policy: Policy, robot: RobotModel) -> None:
    backend = create_backend("fake", robot, fr3_policy, {"speedup": 5.0, "table_height_m": 0.1})
    assert isinstance(backend, FakeBackend)
    assert backend.speedup == 5.0 and backend.table_height_m == 0.1
    assert backend.joint_names == fr3_policy.robot.joint_names
    assert backend.start_tolerance_rad == fr3_policy.motion.start_tolerance_rad
    assert backend.servo.latest.positions.tolist() == list(fr3_policy.robot.home_joint_positions)


def test_create_backend_takes_the_config_model_itself(fr3_policy: Policy, robot: RobotModel) -> None:
    backend = create_backend("fake", robot, fr3_policy, Config(wrench=False))
    assert not backend.capabilities.wrench


def test_an_unknown_backend_lists_the_available_ones(fr3_policy: Policy, robot: RobotModel) -> None:
    with pytest.raises(BackendUnavailable, match="unknown backend 'warp'; choose one of fake, mujoco"):
        create_backend("warp", robot, fr3_policy)


def test_a_backend_whose_dependency_is_missing_names_the_extra(monkeypatch, fr3_policy: Policy, robot: RobotModel) -> None:
    monkeypatch.setitem(backends.BACKENDS, "warp", "armwarden.backends.no_such_module")
    with pytest.raises(BackendUnavailable, match=r"the warp backend is not available: .*install armwarden\[warp\]"):
        create_backend("warp", robot, fr3_policy)


def test_a_backend_config_file_is_validated_by_the_backend_config_model(tmp_path: Path) -> None:
    path = tmp_path / "fake.yaml"
    path.write_text("speedup: 4\ntable_height_m: 0.05\n", encoding="utf-8")
    assert load_backend_config("fake", path) == Config(speedup=4.0, table_height_m=0.05)
    assert load_backend_config("fake", None) == Config()


def test_every_error_of_a_backend_config_is_reported_with_its_yaml_path(tmp_path: Path) -> None:
    path = tmp_path / "fake.yaml"
    path.write_text("speedup: -1\ntable_stiffnes_n_per_m: 5\nwrench: maybe\n", encoding="utf-8")
    with pytest.raises(ConfigurationError) as caught:
        load_backend_config("fake", path)
    message = str(caught.value)
    assert f"invalid fake backend config {path}" in message
    assert "  speedup: " in message and "greater than 0" in message
    assert "  table_stiffnes_n_per_m: unknown key" in message and "did you mean 'table_stiffness_n_per_m'" in message
    assert "  wrench: " in message


@pytest.mark.parametrize("text", ["[1, 2]\n", "speedup: [\n"])
def test_a_backend_config_that_is_not_a_mapping_is_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "fake.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigurationError, match="backend config"):
        load_backend_config("fake", path)


def _serve(tmp_path: Path, *args: str, blocked: str | None = None) -> subprocess.CompletedProcess[str]:
    """`armwarden serve` in a subprocess; `blocked`: a module whose import fails there (a
    sitecustomize sets it to None), as on a machine without the extra that provides it."""
    path = [str(REPO / "src")]
    if blocked is not None:
        site = tmp_path / "site"
        site.mkdir()
        (site / "sitecustomize.py").write_text(f"import sys\nsys.modules[{blocked!r}] = None\n", encoding="utf-8")
        path.insert(0, str(site))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(path))
    return subprocess.run(
        [sys.executable, "-m", "armwarden.cli", "serve", "--audit-log", str(tmp_path / "audit.jsonl"), *args],
        check=False, cwd=REPO, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120,
    )


def test_serve_with_ros2_but_without_rclpy_exits_2_with_the_install_hint(tmp_path: Path) -> None:
    result = _serve(tmp_path, "--backend", "ros2", blocked="rclpy")
    assert result.returncode == 2, result.stderr
    assert "the ros2 backend is not available" in result.stderr
    # a venv of its own, as run.sh builds it: never the ROS wheels into the main venv
    assert "bash scripts/run.sh --backend ros2" in result.stderr and ".venv-ros" in result.stderr
    assert "pip install -e '.[ros]'" not in result.stderr
    assert result.stdout == "" and not (tmp_path / "audit.jsonl").exists()


def test_serve_with_an_invalid_backend_config_exits_2_naming_the_key(tmp_path: Path) -> None:
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 0\n", encoding="utf-8")
    result = _serve(tmp_path, "--backend-config", str(config))
    assert result.returncode == 2, result.stderr
    assert "speedup: " in result.stderr
    assert result.stdout == "" and not (tmp_path / "audit.jsonl").exists()


def test_serve_with_mujoco_missing_exits_2_with_the_install_hint(tmp_path: Path) -> None:
    result = _serve(tmp_path, "--backend", "mujoco", blocked="mujoco")
    assert result.returncode == 2, result.stderr
    assert "the mujoco backend is not available" in result.stderr and "install armwarden[mujoco]" in result.stderr
    assert result.stdout == "" and not (tmp_path / "audit.jsonl").exists()
