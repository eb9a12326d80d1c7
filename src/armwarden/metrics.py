"""Prometheus metrics of one daemon: what an operator scrapes at ``/metrics`` (docs/metrics.md).

Why this shape:

- **One registry per daemon** (`DaemonMetrics.registry`), never prometheus_client's global
  default: no global mutable state, and tests run several daemons in one process.
- **Hooked where the facts already pass, once**, so nothing is missed and nothing is counted
  twice: every `tools/call` — refused before a tool body ran or by it, with its code, its
  approval and its latency — ends in the server middleware's `CallRecord`
  (`observe_call`); every audit record passes the audit writer thread (`observe_audit_write`).
  E-stops (the latch's own tallies, `EStopLatch.tallies`), the backend's arm state
  (`Backend.arm_state`) and servo-loop timing (`ServoLoop.timing`, `TickTiming.totals`) are
  *read at scrape time* by a custom collector, so the latch, the backend and the servo thread
  never call into metrics code at all.
- **Metrics can never break or delay a safety path.** Every hook catches and logs its own
  exceptions (`_swallowed`), holds no lock of ours (prometheus_client's per-value locks are held
  for an addition), and does no I/O. A scrape reads the latch and tick timing under their
  locks for a few attribute loads only.
- **Bounded labels.** Tool names and refusal codes come from clients' requests: a name that is
  not one of ArmWarden's tools is counted as ``unknown``, a code or status that is not one of
  ours as ``other``, so a client cannot grow the series without bound.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, ParamSpec

from prometheus_client import CONTENT_TYPE_LATEST as CONTENT_TYPE
from prometheus_client import CollectorRegistry, Counter, Histogram, Info, ProcessCollector, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from armwarden import __version__
from armwarden.core.errors import RefusalCode
from armwarden.policy import ALL_TOOLS
from armwarden.tools import names

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.callcontext import CallRecord
    from armwarden.safety.estop import EStopLatch

__all__ = ["CONTENT_TYPE", "PLAN_TOOLS", "DaemonMetrics"]

logger = logging.getLogger(__name__)

P = ParamSpec("P")

#: the tools whose latency is also a planning latency, labelled by the plan's status
PLAN_TOOLS = names(lambda spec: spec.plan_kind)
_TOOLS = frozenset(ALL_TOOLS)
_CODES = frozenset(code.value for code in RefusalCode) | {"ERROR"}
_STATUSES = frozenset({"ok", "refused", "invalid", "error", "cancelled", "input_required"})
_PLAN_STATUSES = frozenset({"ok", "needs_approval", "rejected"})
#: approval answers that came from a human (the others: none was needed, or the policy decided)
_HUMAN_CHANNELS = frozenset({"elicitation", "console"})

#: a tool call: from microseconds (a refusal) to minutes (a human deciding, a long motion) [s]
CALL_BUCKETS_S = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0)
#: planning, envelope check included [s]
PLAN_BUCKETS_S = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)
#: an audit record from hand-over to fsynced [s] (read-only calls' records wait for the commit window)
AUDIT_BUCKETS_S = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5)


def _swallowed(method: Callable[P, None]) -> Callable[P, None]:
    """A hook that never raises: metrics must not break the call, the stop or the record it observes."""

    @functools.wraps(method)
    def hook(*args: P.args, **kwargs: P.kwargs) -> None:
        try:
            method(*args, **kwargs)
        except Exception:
            logger.exception("metrics: %s failed (the observed path went on)", method.__name__)

    return hook


class DaemonMetrics:
    """The metrics of one daemon. Build it with the daemon's e-stop `latch` and `backend`, hand
    `observe_call` to the server middleware and `observe_audit_write` to the audit log, and
    serve `exposition()` (content type `CONTENT_TYPE`)."""

    def __init__(self, latch: EStopLatch | None = None, backend: Backend | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self.registry = CollectorRegistry()
        registry = self.registry
        Info("armwarden", "The daemon's version and backend.", registry=registry).info(
            {"version": __version__, "backend": getattr(backend, "name", "none")})
        self.tool_calls = Counter("armwarden_tool_calls", "Tool calls by tool and how they ended.",
                                  ["tool", "status"], registry=registry)
        self.refusals = Counter("armwarden_refusals", "Tool calls refused (or failed closed), by tool and refusal code.",
                                ["tool", "code"], registry=registry)
        self.approvals = Counter("armwarden_approvals", "Questions to a human and their outcomes, by tool.",
                                 ["tool", "outcome"], registry=registry)
        self.call_seconds = Histogram("armwarden_tool_call_duration_seconds",
                                      "From the call reaching the server to its end, human approval included.",
                                      ["tool"], buckets=CALL_BUCKETS_S, registry=registry)
        self.plan_seconds = Histogram("armwarden_plan_duration_seconds",
                                      "Planning calls (envelope check included), by tool and plan status.",
                                      ["tool", "status"], buckets=PLAN_BUCKETS_S, registry=registry)
        self.audit_write_seconds = Histogram("armwarden_audit_write_duration_seconds",
                                             "Audit records from hand-over to fsynced, by durability class.",
                                             ["durability"], buckets=AUDIT_BUCKETS_S, registry=registry)
        registry.register(SafetyStateCollector(latch, backend))
        ProcessCollector(registry=registry)

    # ------------------------------------------------------------------ hooks
    @_swallowed
    def observe_call(self, record: CallRecord) -> None:
        """A finished `tools/call` (any outcome), from its `CallRecord`."""
        tool = record.tool if record.tool in _TOOLS else "unknown"
        outcome = record.outcome or "error"
        status = outcome if outcome in _STATUSES else "other"
        elapsed_s = max(0.0, self._clock() - record.received_mono)
        self.tool_calls.labels(tool, status).inc()
        self.call_seconds.labels(tool).observe(elapsed_s)
        if record.code and outcome != "ok":
            self.refusals.labels(tool, record.code if record.code in _CODES else "other").inc()
        if tool in PLAN_TOOLS and outcome == "ok":
            result = record.extra.get("result")
            plan_status = result.get("status") if isinstance(result, dict) else None
            self.plan_seconds.labels(tool, plan_status if plan_status in _PLAN_STATUSES else "other").observe(elapsed_s)
        self._observe_approval(tool, record)

    def _observe_approval(self, tool: str, record: CallRecord) -> None:
        # under protocol 2026-07-28 (`rounds`) the question goes out in an InputRequiredResult, and
        # the retry carrying its answer runs the approval resolvers again: not a second question
        if "approval_prompt" in record.extra and (record.outcome == "input_required" or not record.rounds):
            self.approvals.labels(tool, "asked").inc()
        approval = record.extra.get("approval")
        if not isinstance(approval, dict) or approval.get("via") not in _HUMAN_CHANNELS:
            return
        if approval.get("granted"):
            outcome = "approved"
        elif approval.get("answer") == "ConsoleAnswer" and not approval.get("operator"):
            outcome = "expired"  # nobody answered in the console before the plan expired (or an e-stop voided it)
        else:
            outcome = "denied"
        self.approvals.labels(tool, outcome).inc()

    @_swallowed
    def observe_audit_write(self, durability: str, seconds: float) -> None:
        """An audit record reached the disk `seconds` after it was handed to the writer (its thread)."""
        self.audit_write_seconds.labels(durability).observe(seconds)

    # ------------------------------------------------------------------ serving
    def exposition(self) -> bytes:
        """The text exposition of every metric (`CONTENT_TYPE`)."""
        return generate_latest(self.registry)


class SafetyStateCollector(Collector):
    """Read at scrape time: the e-stop latch's tallies, the backend's arm state and its servo-loop
    timing. Nothing here runs on the latch's or the servo thread's path; a scrape takes their locks
    for a copy (the arm state is one attribute read)."""

    def __init__(self, latch: EStopLatch | None, backend: Backend | None) -> None:
        self._latch = latch
        self._backend = backend

    def collect(self) -> Iterator[Metric]:
        try:
            yield from self._estops()
            yield from self._arm_state()
            yield from self._servo()
        except Exception:  # a scrape that cannot read the state says less, it never fails the daemon
            logger.exception("metrics: reading the e-stop latch, the arm state or the servo timing failed")

    def _estops(self) -> Iterator[Metric]:
        if self._latch is None:
            return
        by_source, releases = self._latch.tallies()
        latched = CounterMetricFamily("armwarden_estops_latched", "E-stop latches, by what latched them.",
                                      labels=["source"])
        for source, count in sorted(by_source.items()):
            latched.add_metric([source], count)
        yield latched
        yield CounterMetricFamily("armwarden_estops_released", "E-stops released by a human (reset_estop, console).",
                                  value=releases)
        yield GaugeMetricFamily("armwarden_estop_latched", "1 while the e-stop is latched, else 0.",
                                value=1 if self._latch.is_latched else 0)

    def _arm_state(self) -> Iterator[Metric]:
        from armwarden.backends.arm_state import ArmState

        state = getattr(self._backend, "arm_state", None)
        if not isinstance(state, ArmState):
            return
        backend = str(getattr(self._backend, "name", "unknown"))
        gauge = GaugeMetricFamily("armwarden_arm_state", "1 for the state the arm is in, 0 for the others.",
                                  labels=["backend", "state"])
        for each in ArmState:  # every state, always: a query needs no absent series
            gauge.add_metric([backend, each.value], 1 if each is state else 0)
        yield gauge

    def _servo(self) -> Iterator[Metric]:
        from armwarden.backends.servo import ServoLoop

        servo = getattr(self._backend, "servo", None)
        if not isinstance(servo, ServoLoop):
            return  # no periodic loop of ours (the ROS 2 backend: the controller runs it)
        backend = str(getattr(self._backend, "name", "unknown"))
        ticks, misses, max_lateness_s, max_interval_s = servo.timing.totals()

        def family(kind: type[CounterMetricFamily | GaugeMetricFamily], name: str, doc: str, value: float) -> Metric:
            metric = kind(name, doc, labels=["backend"])
            metric.add_metric([backend], value)
            return metric

        yield family(GaugeMetricFamily, "armwarden_servo_period_seconds", "The servo loop's tick period while moving.",
                     servo.period_s)
        yield family(CounterMetricFamily, "armwarden_servo_ticks", "Servo-loop ticks run.", ticks)
        yield family(CounterMetricFamily, "armwarden_servo_deadline_misses",
                     "Servo ticks that began more than one period after they were scheduled.", misses)
        yield family(GaugeMetricFamily, "armwarden_servo_max_lateness_seconds",
                     "The latest any servo tick began after it was scheduled.", max_lateness_s)
        yield family(GaugeMetricFamily, "armwarden_servo_max_interval_seconds",
                     "The longest interval between two servo ticks.", max_interval_s)
