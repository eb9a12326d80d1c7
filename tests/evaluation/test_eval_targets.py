"""`armwarden eval --backend can`: the emulator only, never a bus a real arm may be on.

The evaluation approves its own motions, so a CAN config without `simulate` or with a bus
interface other than `virtual` must be refused before anything starts (exit 2, saying why).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from armwarden.backends import load_backend_config
from armwarden.backends.can.config import Config
from armwarden.cli import main
from armwarden.evaluation import command
from armwarden.evaluation.targets import (
    DEFAULT_CAN_CONFIG,
    EMULATOR_CAN_TIMEOUT_S,
    EMULATOR_RX_TIMEOUT_S,
    checked_can_config,
    default_backend_config,
)

EXIT_REFUSED = 2


def _can_config(tmp_path: Path, **changes: Any) -> Path:
    """examples/can_sim.yaml with top-level `changes` (None removes the key) and `bus_interface`."""
    document = yaml.safe_load(DEFAULT_CAN_CONFIG.read_text(encoding="utf-8"))
    interface = changes.pop("bus_interface", None)
    if interface is not None:
        document["bus"]["interface"] = interface
    for key, value in changes.items():
        if value is None:
            document.pop(key)
        else:
            document[key] = value
    path = tmp_path / "can.yaml"
    path.write_text(yaml.safe_dump(document), encoding="utf-8")
    return path


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Records every evaluation run (the daemons are started only inside `run_evaluation`)."""
    runs: list[Any] = []

    async def run_evaluation(options: Any) -> None:
        runs.append(options)
        raise AssertionError("the evaluation must not start")

    monkeypatch.setattr(command, "run_evaluation", run_evaluation)
    return runs


@pytest.mark.parametrize(("changes", "why"), [
    ({"bus_interface": "socketcan"}, "its bus interface is 'socketcan', not 'virtual'"),
    ({"simulate": None}, "it has no `simulate` section"),
    ({"simulate": None, "bus_interface": "pcan"}, "no `simulate` section (the actuators would be real ones on the "
                                                  "bus); its bus interface is 'pcan'"),
])
def test_a_can_config_that_may_reach_hardware_is_refused_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], started: list[Any], changes: dict[str, Any],
        why: str) -> None:
    config = _can_config(tmp_path, **changes)
    code = main(["eval", "--quick", "--backend", "can", "--backend-config", str(config),
                 "--json", str(tmp_path / "eval.json")])
    err = capsys.readouterr().err
    assert code == EXIT_REFUSED
    assert why in err and "never runs on hardware" in err and str(config) in err
    assert started == [] and not (tmp_path / "eval.json").exists()


def test_an_invalid_can_config_is_refused_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], started: list[Any]) -> None:
    config = tmp_path / "can.yaml"
    config.write_text("bus: {interface: virtual, channel: x}\nsimulate: {}\njoints: []\n", encoding="utf-8")
    assert main(["eval", "--backend", "can", "--backend-config", str(config)]) == EXIT_REFUSED
    assert "invalid CAN backend config" in capsys.readouterr().err
    assert started == []


def test_the_daemon_gets_a_checked_copy_of_the_default_emulator_with_only_its_watchdogs_widened(
        tmp_path: Path) -> None:
    assert default_backend_config("can") == DEFAULT_CAN_CONFIG
    assert default_backend_config("fake") is None and default_backend_config("mujoco") is None
    copy = checked_can_config(DEFAULT_CAN_CONFIG, tmp_path)
    assert copy.parent == tmp_path
    given = load_backend_config("can", DEFAULT_CAN_CONFIG)
    used = load_backend_config("can", copy)
    assert isinstance(used, Config) and isinstance(given, Config)
    assert (used.rx_timeout_s, used.can_timeout_s) == (EMULATOR_RX_TIMEOUT_S, EMULATOR_CAN_TIMEOUT_S)
    assert used.model_copy(update={"rx_timeout_s": given.rx_timeout_s, "can_timeout_s": given.can_timeout_s}) == given


def test_eval_on_can_without_a_config_runs_the_checked_emulator(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, started: list[Any]) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "--quick", "--backend", "can"]) == EXIT_REFUSED  # the stub refuses to run
    (options,) = started
    assert options.backend == "can" and options.backend_config.name == "can-config.yaml"
    assert not options.backend_config.exists()  # the private copy went with the run
