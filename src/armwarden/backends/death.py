"""Evaluation only: a simulated backend made to die through its real failure path.

`armwarden eval` checks that a backend dying mid-motion (its control or physics thread, its
emulated actuators going silent) latches the e-stop, is reported and refuses every later motion.
The daemon is another process, so the death is asked for from outside: `armwarden serve
--eval-backend-death` (refused at start-up for any backend that may drive a real arm) lets SIGUSR2
call `inject_death` (`armwarden.daemon.death`). Nothing else calls it.

The death is never a shortcut to the outcome under test: it breaks the simulation (a worker raises
at its next checkpoint, the emulator stops answering) and the backend then finds and reports it the
way it would a real failure (`_worker_died`, the CAN backend's RX timeout). A backend offers it
by overriding `why_no_injected_death` (None: it is a simulation) and `_inject_death`; the default
refuses, so a backend that does nothing about it — ROS 2, a plug-in's, anything that may hold a
real arm — can never be told to die.
"""

from __future__ import annotations

import abc

from armwarden.core.errors import BackendError


class InjectedBackendDeath(RuntimeError):
    """What a simulated worker raises when the evaluation injected its death (named in the fault)."""


class DeathInjection(abc.ABC):
    """The evaluation's seam for a backend's death (a part of `Backend`; see the module docstring)."""

    # provided by `Backend`
    name: str

    @abc.abstractmethod
    def _require_open(self) -> None: ...

    @abc.abstractmethod
    def inject_worker_failure(self, worker: str, error: BaseException) -> None: ...

    def why_no_injected_death(self) -> str | None:
        """Why this backend's death cannot be injected, or None when it is a simulation whose death
        can. Default: it may drive a real arm, so never (a backend opts in by overriding this)."""
        return (f"the {self.name} backend may drive a real arm: an injected death is offered only by a simulated "
                "backend (fake, mujoco, can on its emulator)")

    def inject_death(self) -> str:
        """Make the backend die through its real failure path (see the module docstring); returns
        what was broken. `BackendError` when this backend offers no injected death, or is not open."""
        why = self.why_no_injected_death()
        if why is not None:
            raise BackendError(why)
        self._require_open()
        return self._inject_death()

    def _inject_death(self) -> str:
        """Hook: break the simulation so the backend finds the failure itself; returns what was broken."""
        raise BackendError(f"the {self.name} backend has no injected death")

    def _kill_worker(self, worker: str) -> str:
        """The common death: `worker` raises `InjectedBackendDeath` at its next checkpoint and dies
        through its real failure path (`WorkerSupervision.inject_worker_failure`)."""
        self.inject_worker_failure(worker, InjectedBackendDeath(f"evaluation: the {worker} thread made to die"))
        return f"the {worker} thread raises at its next turn"


__all__ = ["DeathInjection", "InjectedBackendDeath"]
