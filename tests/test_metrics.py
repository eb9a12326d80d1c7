"""`armwarden.metrics` without a daemon: what a finished call's record counts, the e-stop latch
and the audit writer read through their hooks, bounded labels, hooks that never raise, and
``/metrics`` beside the stdio daemon's console (`build_console_only_app`)."""

from __future__ import annotations

import re
from pathlib import Path

import httpx2
import pytest
from prometheus_client.parser import text_string_to_metric_families
from starlette.responses import PlainTextResponse
from starlette.types import Receive, Scope, Send

from armwarden.audit import AuditLog
from armwarden.backends.arm_state import ArmState
from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.servo import ServoHooks, ServoLoop
from armwarden.callcontext import CallRecord
from armwarden.metrics import DaemonMetrics
from armwarden.safety.estop import EStopLatch
from armwarden.transport.http import build_console_only_app
from armwarden.transport.jsonrpc import RefusedRequest
from armwarden.transport.tokens import TokenStore
from tests.helpers import REPO, run_opened


def scraped(metrics: DaemonMetrics) -> dict[tuple[str, frozenset[tuple[str, str]]], float]:
    text = metrics.exposition().decode()
    return {(s.name, frozenset(s.labels.items())): s.value for f in text_string_to_metric_families(text) for s in f.samples}


def value(metrics: DaemonMetrics, name: str, **labels: str) -> float:
    return scraped(metrics).get((name, frozenset(labels.items())), 0.0)


def finished(tool: str, outcome: str, code: str | None = None, rounds: bool = False, **extra: object) -> CallRecord:
    return CallRecord(tool=tool, arguments={}, outcome=outcome, code=code, extra=dict(extra), rounds=rounds)


def test_each_daemon_has_a_registry_of_its_own() -> None:
    first, second = DaemonMetrics(), DaemonMetrics()
    first.observe_call(finished("get_robot_state", "ok"))
    assert value(first, "armwarden_tool_calls_total", tool="get_robot_state", status="ok") == 1
    assert value(second, "armwarden_tool_calls_total", tool="get_robot_state", status="ok") == 0


def test_a_refusal_is_counted_by_tool_and_code_and_a_success_is_not() -> None:
    metrics = DaemonMetrics()
    metrics.observe_call(finished("execute_plan", "refused", "EXPIRED_PLAN"))
    metrics.observe_call(finished("execute_plan", "ok"))
    assert value(metrics, "armwarden_refusals_total", tool="execute_plan", code="EXPIRED_PLAN") == 1
    assert value(metrics, "armwarden_tool_calls_total", tool="execute_plan", status="refused") == 1
    assert value(metrics, "armwarden_tool_calls_total", tool="execute_plan", status="ok") == 1
    assert value(metrics, "armwarden_tool_call_duration_seconds_count", tool="execute_plan") == 2


def test_names_a_client_made_up_are_folded_so_series_stay_bounded() -> None:
    metrics = DaemonMetrics()
    for n in range(50):
        metrics.observe_call(finished(f"tool_{n}", "invalid", f"CODE_{n}"))
    assert value(metrics, "armwarden_tool_calls_total", tool="unknown", status="invalid") == 50
    assert value(metrics, "armwarden_refusals_total", tool="unknown", code="other") == 50
    assert not any(name == "armwarden_tool_calls_total" and ("tool", "tool_1") in labels
                   for name, labels in scraped(metrics))


def test_a_plan_is_timed_under_its_status() -> None:
    metrics = DaemonMetrics()
    metrics.observe_call(finished("plan_to_pose", "ok", result={"status": "needs_approval"}))
    assert value(metrics, "armwarden_plan_duration_seconds_count", tool="plan_to_pose", status="needs_approval") == 1


@pytest.mark.parametrize(("approval", "outcome"), [
    ({"granted": True, "via": "elicitation", "operator": "alice", "answer": "AcceptedElicitation"}, "approved"),
    ({"granted": False, "via": "elicitation", "operator": None, "answer": "DeclinedElicitation"}, "denied"),
    ({"granted": False, "via": "console", "operator": "carol", "answer": "ConsoleAnswer"}, "denied"),
    ({"granted": False, "via": "console", "operator": None, "answer": "ConsoleAnswer"}, "expired"),
], ids=["approved", "declined_in_the_form", "declined_in_the_console", "unanswered_in_the_console"])
def test_a_question_asked_mid_call_and_its_answer_are_counted(approval, outcome) -> None:
    metrics = DaemonMetrics()
    metrics.observe_call(finished("execute_plan", "ok" if approval["granted"] else "refused",
                                  None if approval["granted"] else "APPROVAL_DENIED",
                                  approval_prompt="APPROVE ROBOT MOTION?", approval=approval))
    assert value(metrics, "armwarden_approvals_total", tool="execute_plan", outcome="asked") == 1
    assert value(metrics, "armwarden_approvals_total", tool="execute_plan", outcome=outcome) == 1


def test_a_question_asked_in_rounds_is_counted_once() -> None:
    """Protocol 2026-07-28: the question goes out in an InputRequiredResult; the retry carrying
    the answer runs the resolvers (and notes the prompt) again."""
    metrics = DaemonMetrics()
    metrics.observe_call(finished("reset_estop", "input_required", rounds=True, approval_prompt="RELEASE?"))
    metrics.observe_call(finished("reset_estop", "ok", rounds=True, approval_prompt="RELEASE?",
                                  approval={"granted": True, "via": "elicitation", "operator": "bob",
                                            "answer": "AcceptedElicitation"}))
    assert value(metrics, "armwarden_approvals_total", tool="reset_estop", outcome="asked") == 1
    assert value(metrics, "armwarden_approvals_total", tool="reset_estop", outcome="approved") == 1


def test_an_approval_nobody_was_asked_for_is_not_counted() -> None:
    metrics = DaemonMetrics()
    metrics.observe_call(finished("execute_plan", "ok", approval={"granted": True, "via": "not_required",
                                                                  "operator": None, "answer": "AcceptedElicitation"}))
    assert not [key for key in scraped(metrics) if key[0] == "armwarden_approvals_total"]


def test_a_hook_that_fails_is_logged_and_never_raises(caplog) -> None:
    metrics = DaemonMetrics()
    broken = CallRecord(tool="get_robot_state", arguments={}, outcome="ok")
    broken.received_mono = "not a time"  # type: ignore[assignment]
    metrics.observe_call(broken)
    metrics.observe_audit_write("now", "not seconds")  # type: ignore[arg-type]
    assert "metrics: observe_call failed" in caplog.text
    assert "metrics: observe_audit_write failed" in caplog.text


def test_estops_are_read_from_the_latch_at_scrape_time() -> None:
    latch = EStopLatch()
    metrics = DaemonMetrics(latch)
    latch.latch("operator pressed it", "estop")
    latch.latch("over the force limit", "force_monitor")
    second = latch.latch("again", "estop")
    assert value(metrics, "armwarden_estop_latched") == 1
    assert latch.release(second.number).released
    assert value(metrics, "armwarden_estops_latched_total", source="estop") == 2
    assert value(metrics, "armwarden_estops_latched_total", source="force_monitor") == 1
    assert value(metrics, "armwarden_estops_released_total") == 1
    assert value(metrics, "armwarden_estop_latched") == 0


def test_the_arm_state_is_read_from_the_backend_at_scrape_time() -> None:
    backend = FakeBackend()
    metrics = DaemonMetrics(EStopLatch(), backend)
    assert value(metrics, "armwarden_arm_state", backend="fake", state="closed") == 1

    async def opened(_backend: FakeBackend) -> dict[str, float]:
        return {state.value: value(metrics, "armwarden_arm_state", backend="fake", state=state.value)
                for state in ArmState}

    assert run_opened(lambda: backend, opened) == {"closed": 0, "idle": 1, "moving": 0, "held": 0, "damped": 0,
                                                   "faulted": 0}


def test_every_audit_record_is_timed_to_the_disk(tmp_path: Path) -> None:
    metrics = DaemonMetrics()
    with AuditLog(tmp_path / "audit.jsonl", commit_window_s=0.02) as audit:
        audit.observe_writes(metrics.observe_audit_write)
        audit.submit("estop", outcome="latched")
        audit.append_soon("tool_call", tool="get_robot_state", outcome="ok")
        audit.flush()
    assert value(metrics, "armwarden_audit_write_duration_seconds_count", durability="now") == 1
    assert value(metrics, "armwarden_audit_write_duration_seconds_count", durability="window") == 1


# ------------------------------------------------------------------ beside the stdio daemon's console
async def no_console(scope: Scope, receive: Receive, send: Send) -> None:
    await PlainTextResponse("console")(scope, receive, send)


@pytest.mark.anyio
async def test_the_console_port_serves_metrics_behind_the_token_file(tmp_path: Path) -> None:
    tokens = tmp_path / "tokens.json"
    observer = TokenStore.add(tokens, "observer", name="watcher")
    refused: list[RefusedRequest] = []

    async def on_refused(request: RefusedRequest) -> None:
        refused.append(request)

    metrics = DaemonMetrics()
    app = build_console_only_app(no_console, host="127.0.0.1", port=8799, metrics=metrics.exposition,
                                 token_store=TokenStore.load(tokens), on_refused=on_refused)
    transport = httpx2.ASGITransport(app=app)
    async with httpx2.AsyncClient(transport=transport, base_url="http://127.0.0.1:8799") as client:
        assert (await client.get("/metrics")).status_code == 401
        assert (await client.get("/metrics", headers={"Authorization": "Bearer aw_wrong"})).status_code == 401
        served = await client.get("/metrics", headers={"Authorization": f"Bearer {observer}"})
    assert served.status_code == 200
    assert "armwarden_info" in served.text
    assert len(refused) == 2 and all("/metrics refused (401)" in r.why for r in refused)


def test_docs_name_every_metric_the_daemon_exposes() -> None:
    class ServoBackend:
        name = "fake"
        arm_state = ArmState.IDLE
        servo = ServoLoop(ServoHooks(), [0.0] * 7, period_s=0.001)  # never started: its timing reads zero

    metrics = DaemonMetrics(EStopLatch(), ServoBackend())  # type: ignore[arg-type]
    names = {family.name for family in text_string_to_metric_families(metrics.exposition().decode())
             if family.name.startswith("armwarden_")}
    documented = set(re.findall(r"`(armwarden_[a-z_]+)`", (REPO / "docs" / "metrics.md").read_text(encoding="utf-8")))
    exposed = {name + "_total" if name + "_total" in documented else name for name in names}
    assert len(exposed) >= 14
    assert exposed <= documented, sorted(exposed - documented)
