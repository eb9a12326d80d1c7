"""Which arm the evaluation may drive: it approves its own motions, so never a physical one.

`fake` and `mujoco` are simulations by construction. `can` is allowed only when its backend
config runs the emulator: a `simulate` section (the actuators are emulated in-process) *and* the
bus interface `virtual` (python-can's in-process bus, which no hardware is on). Anything else —
socketcan, a USB adapter, or a virtual bus without the emulator, which another process on this
host could be bridging to hardware — is refused before anything is started.

The check reads the config with the daemon's own loader (`load_backend_config`), and the daemon is
then given a private copy, checked again as written, so a file edited after the check cannot put
a real bus under an evaluation that approves its own motions.

The copy widens two watchdogs of the emulator, as the test harness does (backends/can/testing.py):
the emulated actuators are threads of the daemon's own process, so anything that holds the
interpreter for a few hundred milliseconds on a loaded machine (planning in C++ holds the GIL)
also silences every actuator, and an RX timeout of 0.25 s then latches the e-stop on a stall of the
host, not of the bus: the evaluation would report the machine's load as failed scenarios. No
scenario tests these watchdogs, and no Guard check is touched; the widening is said on stderr.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import yaml

from armwarden.core.errors import ArmWardenError
from armwarden.evaluation.runner import progress

if TYPE_CHECKING:
    from armwarden.backends.can.config import Config as CanConfig

#: the emulated arm the evaluation runs `--backend can` on when no config is given (a source checkout's)
DEFAULT_CAN_CONFIG = Path(__file__).resolve().parents[3] / "examples" / "can_sim.yaml"
#: the interface of python-can's in-process bus: frames never leave this process
VIRTUAL_INTERFACE = "virtual"
#: the emulator's watchdogs in the evaluation, at least: an unanswered command [s], a silent host [s]
EMULATOR_RX_TIMEOUT_S = 1.0
EMULATOR_CAN_TIMEOUT_S = 2.0


class EvalRefused(ArmWardenError):
    """The evaluation will not run on this backend configuration (exit 2, nothing started)."""


def default_backend_config(backend: str) -> Path | None:
    """The config the evaluation uses when none is given: the emulated arm for `can`, else None
    (the backend's own defaults)."""
    if backend != "can":
        return None
    if not DEFAULT_CAN_CONFIG.is_file():
        raise EvalRefused(f"--backend can needs --backend-config: the default {DEFAULT_CAN_CONFIG} is not there "
                          "(it ships with a source checkout only)")
    return DEFAULT_CAN_CONFIG


def why_not_emulated(config: object) -> str | None:
    """Why a validated CAN `Config` may reach hardware, or None when it is the emulator on the virtual bus."""
    simulate = getattr(config, "simulate", None)
    interface = getattr(getattr(config, "bus", None), "interface", None)
    reasons = []
    if simulate is None:
        reasons.append("it has no `simulate` section (the actuators would be real ones on the bus)")
    if interface != VIRTUAL_INTERFACE:
        reasons.append(f"its bus interface is {interface!r}, not {VIRTUAL_INTERFACE!r} (a real CAN bus)")
    return "; ".join(reasons) or None


def checked_can_config(path: Path, directory: Path) -> Path:
    """A private copy, in `directory`, of the CAN config at `path` once it is shown to run the
    emulator on the virtual bus (its watchdogs widened, see the module docstring); `EvalRefused`
    saying why otherwise (also for an unreadable or invalid config). The copy is checked as written."""
    config = _emulated_can(path, path)
    widened = {"rx_timeout_s": max(config.rx_timeout_s, EMULATOR_RX_TIMEOUT_S),
               "can_timeout_s": max(config.can_timeout_s, EMULATOR_CAN_TIMEOUT_S)}
    copy = directory / "can-config.yaml"
    copy.write_text(yaml.safe_dump(config.model_dump(mode="json") | widened, sort_keys=False), encoding="utf-8")
    _emulated_can(copy, path)
    progress(f"can: the emulator's watchdogs widened to rx_timeout_s {widened['rx_timeout_s']:g} s, "
             f"can_timeout_s {widened['can_timeout_s']:g} s (in-process emulator: a host stall is not a bus fault)")
    return copy


def _emulated_can(source: Path, named: Path) -> CanConfig:
    """The CAN config at `source`, read by the daemon's own loader; `EvalRefused` (naming `named`)
    if it is invalid or may reach hardware."""
    from armwarden.backends import load_backend_config  # python-can and pydantic models: only for --backend can
    from armwarden.backends.can.config import Config

    try:
        config = load_backend_config("can", source)
    except ArmWardenError as exc:
        raise EvalRefused(f"invalid CAN backend config {named}: {exc}") from exc
    assert isinstance(config, Config)
    why = why_not_emulated(config)
    if why is not None:
        raise EvalRefused(f"refusing --backend can with {named}: {why}. The evaluation approves its own motions, "
                          "so it never runs on hardware: only the emulator (`simulate` present, bus interface "
                          f"{VIRTUAL_INTERFACE!r}, e.g. examples/can_sim.yaml)")
    return config


__all__ = ["DEFAULT_CAN_CONFIG", "EvalRefused", "checked_can_config", "default_backend_config", "why_not_emulated"]

