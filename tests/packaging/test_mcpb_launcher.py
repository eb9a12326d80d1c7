"""The bundle's launcher (scripts/mcpb_launcher.py → server/main.py): the host's settings → `armwarden serve`.

No mcpb CLI needed: these run everywhere. The bundle built and served end to end is in test_mcpb.py.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from types import ModuleType

import pytest

from tests.helpers import REPO, child_env

LAUNCHER = REPO / "scripts" / "mcpb_launcher.py"


@pytest.fixture(scope="module")
def launcher() -> ModuleType:
    spec = importlib.util.spec_from_file_location("armwarden_mcpb_launcher", LAUNCHER)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_empty_settings_leave_the_daemons_defaults_but_the_audit_log_goes_home(launcher: ModuleType) -> None:
    """The daemon's own default audit log is relative to its working directory, which the host
    picks (often `/`): the launcher puts it in the user's home directory and says so."""
    environ = {"ARMWARDEN_POLICY": "", "ARMWARDEN_BACKEND": " ", "ARMWARDEN_BACKEND_CONFIG": "", "ARMWARDEN_AUDIT_LOG": "",
               "HOME": "/home/u"}
    notes: list[str] = []
    assert launcher.serve_arguments(environ, say=notes.append) == ["serve", "--audit-log", "/home/u/armwarden-audit.jsonl"]
    assert notes == ["ARMWARDEN_AUDIT_LOG is empty (no audit log in the extension's settings): "
                     "the audit log is /home/u/armwarden-audit.jsonl"]


def test_a_set_audit_log_is_passed_on_without_a_note(launcher: ModuleType) -> None:
    notes: list[str] = []
    environ = {"ARMWARDEN_AUDIT_LOG": "/var/log/arm.jsonl", "HOME": "/home/u"}
    assert launcher.serve_arguments(environ, say=notes.append) == ["serve", "--audit-log", "/var/log/arm.jsonl"]
    assert notes == []


def test_an_empty_audit_log_without_a_home_directory_is_refused(launcher: ModuleType) -> None:
    with pytest.raises(launcher.RefusedSetting, match="no home directory"):
        launcher.serve_arguments({"ARMWARDEN_AUDIT_LOG": "", "HOME": "relative/home"})


def test_launcher_says_on_stderr_where_it_put_the_audit_log(tmp_path) -> None:
    """`--help` after the settings: the daemon prints its help and exits, having opened nothing."""
    env = {**child_env(), "HOME": str(tmp_path), "ARMWARDEN_AUDIT_LOG": ""}
    result = subprocess.run([sys.executable, str(LAUNCHER), "--help"], env=env, cwd=tmp_path, input="",
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    assert f"the audit log is {tmp_path / 'armwarden-audit.jsonl'}" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_each_setting_becomes_its_serve_option(launcher: ModuleType) -> None:
    environ = {"ARMWARDEN_POLICY": "/p/policy.yaml", "ARMWARDEN_BACKEND": "mujoco",
               "ARMWARDEN_BACKEND_CONFIG": "/p/scene.yaml", "ARMWARDEN_AUDIT_LOG": "/p/audit.jsonl"}
    assert launcher.serve_arguments(environ, ["--dry-run"]) == [
        "serve", "--policy", "/p/policy.yaml", "--backend", "mujoco", "--backend-config", "/p/scene.yaml",
        "--audit-log", "/p/audit.jsonl", "--dry-run"]


def test_a_placeholder_the_host_did_not_fill_in_is_refused(launcher: ModuleType) -> None:
    with pytest.raises(launcher.UnfilledSetting, match=r"ARMWARDEN_POLICY is '\$\{user_config.policy\}'"):
        launcher.serve_arguments({"ARMWARDEN_POLICY": "${user_config.policy}"})


def test_launcher_exits_2_before_serving_on_a_placeholder(tmp_path) -> None:
    env = {"PATH": "/usr/bin:/bin", "ARMWARDEN_AUDIT_LOG": "${user_config.audit_log}"}
    result = subprocess.run([sys.executable, str(LAUNCHER)], env=env, cwd=tmp_path, input="", capture_output=True,
                            text=True, timeout=60, check=False)
    assert result.returncode == 2
    assert "ARMWARDEN_AUDIT_LOG is '${user_config.audit_log}'" in result.stderr
    assert list(tmp_path.iterdir()) == []  # no audit log, no literal "${user_config.audit_log}" file


def test_build_script_without_the_cli_refuses_when_validation_is_required(tmp_path) -> None:
    out = tmp_path / "armwarden.mcpb"
    result = subprocess.run([sys.executable, str(REPO / "scripts" / "build_mcpb.py"), "--out", str(out),
                             "--mcpb", str(tmp_path / "no-mcpb"), "--require-validation"],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 1
    assert "npm ci --prefix tools/mcpb" in result.stderr
    assert not out.exists()
