"""Evaluation only: `serve --eval-backend-death`, SIGUSR2 makes the simulated backend die.

`armwarden eval` checks that a backend dying mid-motion is latched, reported and refused; the
daemon is another process, so the death is asked for with a signal. The flag is refused at
start-up (exit 2) unless the backend is a simulation: by name first (fake, mujoco, can), then by
the built backend itself (`Backend.why_no_injected_death`: the CAN backend only on its emulator
and the virtual bus). It is written into the start-up audit record. Without the flag nothing here
runs and SIGUSR2 keeps its default action.

On each SIGUSR2 the injection's record (`eval_backend_death`) is handed to the audit writer, so it
comes before any the death causes, and then the backend is broken (`Backend.inject_death`, on a
worker thread: the CAN emulator joins its thread); what follows — the fault, the e-stop latch, its
record — is the backend's and the Guard's own failure path.
"""

from __future__ import annotations

import logging
import signal
from typing import TYPE_CHECKING

import anyio

from armwarden.audit import AuditWriteError
from armwarden.core.errors import BackendError, ConfigurationError

if TYPE_CHECKING:  # light to import: the evaluation reads the signal and the event name from here
    from armwarden.backends.base import Backend
    from armwarden.daemon.startup import Assembly

logger = logging.getLogger("armwarden")

#: the signal that makes the backend die while `--eval-backend-death` is given
DEATH_SIGNAL = signal.SIGUSR2
#: the backends that may be simulations (each one still says so itself once built)
INJECTABLE_BACKENDS = ("fake", "mujoco", "can")
#: the audit event of one injection
DEATH_EVENT = "eval_backend_death"


def refuse_unless_simulated(backend_name: str, backend: Backend | None = None) -> None:
    """`ConfigurationError` (a refused start) unless `backend_name` — and `backend`, once built —
    is a simulation whose death can be injected."""
    if backend_name not in INJECTABLE_BACKENDS:
        raise ConfigurationError(f"--eval-backend-death is for evaluation on a simulated backend "
                                 f"({', '.join(INJECTABLE_BACKENDS)}), not {backend_name!r}, which may drive a real arm")
    why = None if backend is None else backend.why_no_injected_death()
    if why is not None:
        raise ConfigurationError(f"--eval-backend-death refused: {why}")


async def die_on_signal(assembly: Assembly) -> None:
    """Each SIGUSR2: record the injection, then break the backend (see the module docstring)."""
    with anyio.open_signal_receiver(DEATH_SIGNAL) as signals:
        async for _ in signals:
            logger.warning("SIGUSR2 with --eval-backend-death: the %s backend is made to die (evaluation only)",
                           assembly.backend.name)
            try:  # handed to the writer, not waited for: the death must land mid-motion, right now
                assembly.audit.submit(DEATH_EVENT, outcome="injected",
                                      detail=f"SIGUSR2: the {assembly.backend.name} backend made to die "
                                             "(--eval-backend-death, evaluation only)")
            except AuditWriteError as exc:  # the injection goes on: what it checks is recorded by the Guard
                logger.error("the injected death could not be recorded: %s", exc)
            try:
                what = await anyio.to_thread.run_sync(assembly.backend.inject_death)
            except BackendError as exc:
                logger.error("the injected death was refused: %s", exc)
                continue
            logger.warning("injected death: %s", what)


__all__ = ["DEATH_EVENT", "DEATH_SIGNAL", "INJECTABLE_BACKENDS", "die_on_signal", "refuse_unless_simulated"]
