"""Start-up: build everything that can fail before serving (each failure a clean exit 2), open
the backend and wire the Guard, the tool server and the metrics to it; then set the interpreter up
for a long-lived daemon (switch interval, garbage collector)."""

from __future__ import annotations

import gc
from dataclasses import dataclass, field
from typing import Any

from armwarden.assembly import build_backend, build_guard, plan_previewer
from armwarden.audit import DEFAULT_COMMIT_WINDOW_S, AuditLog, hmac_key_for_serving
from armwarden.backends.base import Backend
from armwarden.core.errors import ArmWardenError, BackendUnavailable
from armwarden.daemon.previous_run import unclean_end
from armwarden.guard import Guard
from armwarden.metrics import DaemonMetrics
from armwarden.policy import Policy
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.robot import RobotModel, build_robot
from armwarden.safety.refusals import RefusalReports, left_out_recorder
from armwarden.server.app import ArmWardenServer

#: GIL hand-off interval while planning runs on its worker thread: bounds how long a stop request
#: on the event loop can wait for the interpreter [s] (CPython's default is 5 ms)
SWITCH_INTERVAL_S = 0.0005


#: allocations between two young-generation collections (CPython's default is 700; 2000 from 3.13):
#: fewer collections, so fewer of the interpreter-wide pauses that even the stop channel waits out
GC_YOUNG_THRESHOLD = 10_000


@dataclass(frozen=True)
class AssemblyParts:
    """What `assemble` built before anything is opened: each of these could refuse the start."""

    policy: Policy
    backend: Backend
    audit: AuditLog
    #: the planning thread's model
    runtime: RuntimeModel
    #: the loop-side model the backend's state is read with
    state_robot: RobotModel
    #: why the previous run on this audit log did not end clean (`previous_run`), so this one
    #: starts with the e-stop latched; None: it did, or there was none
    unclean_end: str | None = None

@dataclass
class Assembly:
    policy: Policy
    backend: Backend
    audit: AuditLog
    guard: Guard
    server: ArmWardenServer
    #: what `/metrics` serves (docs/metrics.md)
    metrics: DaemonMetrics | None = None
    #: the limits on records of refused requests of every door: closed (their counts of refusals
    #: left out recorded) before the final record
    refusal_reports: list[RefusalReports] = field(default_factory=list)

    def refusal_reports_for(self, door: str, **options: Any) -> RefusalReports:
        """A limit on records of `door`'s refusals whose counts left out reach this log; closed by
        `close_assembly`."""
        reports = RefusalReports(on_left_out=left_out_recorder(self.audit, door), **options)
        self.refusal_reports.append(reports)
        return reports


def assemble(policy: Policy, backend_name: str, backend_config: str | None, audit_path: str,
             commit_window_s: float = DEFAULT_COMMIT_WINDOW_S, actuation_journal: str | None = None) -> AssemblyParts:
    """Build everything that can fail before serving (each failure is a clean exit 2).
    ``commit_window_s``: the audit log's group-commit window for read-only calls' records;
    ``actuation_journal``: wrap the backend in a `JournalBackend` writing there (`armwarden eval`)."""
    runtime = load_runtime_model(policy)
    state_robot = build_robot(policy)
    backend = build_backend(backend_name, policy, robot=state_robot, config_path=backend_config)
    if actuation_journal is not None:
        from armwarden.backends.journal import JournalBackend

        backend = JournalBackend(backend, actuation_journal)
    audit = AuditLog(audit_path, hmac_key=hmac_key_for_serving(), commit_window_s=commit_window_s)
    return AssemblyParts(policy, backend, audit, runtime, state_robot, unclean_end(audit))


async def open_assembly(parts: AssemblyParts) -> Assembly:
    """Open the backend (a failure is `BackendUnavailable`) and wire the Guard, metrics and tool
    server to it."""
    policy, backend, audit = parts.policy, parts.backend, parts.audit
    try:
        await backend.open()
    except ArmWardenError:
        raise
    except Exception as exc:
        raise BackendUnavailable(f"backend {backend.name} could not be opened: {exc}") from exc
    guard = build_guard(policy, backend, audit, previewer=plan_previewer(), runtime=parts.runtime,
                        robot=parts.state_robot)
    metrics = DaemonMetrics(guard.latch, backend)
    audit.observe_writes(metrics.observe_audit_write)
    server = ArmWardenServer(guard, metrics=metrics)
    return Assembly(policy, backend, audit, guard, server, metrics)


def freeze_long_lived_objects() -> None:
    """Everything built so far lives as long as the daemon: keep it out of every later garbage
    collection, and collect the young generation less often. A collection holds the interpreter
    lock, so its length bounds how long the stop channel's and the servo loop's threads can wait
    (docs/benchmarks.md, "E-stop under a flood"; a physics backend's clock stalls meanwhile)."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(GC_YOUNG_THRESHOLD, *gc.get_threshold()[1:])
