"""A start whose previous run on the same audit log did not end clean latches the e-stop until a
human releases it: a kill mid-motion, a torn last write, an e-stop never released, a shutdown that
could not stop the arm. A clean shutdown starts unlatched. Real daemons over stdio for the kill and
the restart; the log alone for each way a run can end."""

from __future__ import annotations

import socket
from pathlib import Path
from typing import Any

import anyio
import pytest
from mcp import Client, StdioServerParameters
from mcp.client.stdio import stdio_client

from armwarden.audit import AuditLog, verify_file
from armwarden.daemon.previous_run import PREVIOUS_RUN_SOURCE, unclean_end
from tests.helpers import CLI, REPO, child_env, records_of, text_of
from tests.server.harness import approve
from tests.server.test_audit_kill import kill_at_once
from tests.server.test_daemon_stdio import backend_config, serve_params, start_motion, start_raw_daemon, stop_raw_daemon

SPEEDUP = 10.0


# ------------------------------------------------------------------ how the previous run ended, from the log alone
def log_ending_with(tmp_path: Path, event: str | None, **fields: Any) -> Path:
    """A log of one run: its start, then `event` (None: nothing more) as its last record."""
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        log.append("startup", outcome="ok")
        if event is not None:
            log.append(event, **fields)
    return path


def ending_of(path: Path) -> str | None:
    with AuditLog(path) as log:
        return unclean_end(log)


def clean_shutdown(**extra: Any) -> dict[str, Any]:
    return {"outcome": "ok", "extra": {"arm_stopped": True, "estops_held": [], **extra}}


def test_a_new_log_has_no_previous_run_to_latch_for(tmp_path) -> None:
    assert ending_of(tmp_path / "audit.jsonl") is None


def test_a_shutdown_that_stopped_the_arm_with_no_estop_held_is_a_clean_end(tmp_path) -> None:
    assert ending_of(log_ending_with(tmp_path, "shutdown", **clean_shutdown())) is None


def test_a_run_whose_last_record_is_not_its_shutdown_ended_unclean(tmp_path) -> None:
    why = ending_of(log_ending_with(tmp_path, "tool_call", tool="execute_plan", outcome="ok"))
    assert why is not None and "without its shutdown record" in why and "tool_call" in why


def test_a_torn_last_write_is_an_unclean_end(tmp_path) -> None:
    path = log_ending_with(tmp_path, None)
    with path.open("ab") as torn:
        torn.write(b'{"event":"tool_call","seq":2,"de')  # the kill came mid-write
    why = ending_of(path)
    assert why is not None and "cut off mid-write" in why


def test_a_shutdown_with_an_estop_held_names_the_estop_never_released(tmp_path) -> None:
    held = [{"number": 3, "source": "force_monitor", "reason": "force monitor: 41 N at the TCP"}]
    why = ending_of(log_ending_with(tmp_path, "shutdown", **clean_shutdown(estops_held=held)))
    assert why is not None and "e-stop #3 (force_monitor: force monitor: 41 N at the TCP)" in why


def test_a_shutdown_whose_stop_failed_is_an_unclean_end(tmp_path) -> None:
    why = ending_of(log_ending_with(tmp_path, "shutdown", **clean_shutdown(arm_stopped=False)))
    assert why is not None and "could not stop the arm" in why


def test_a_shutdown_record_that_does_not_say_how_it_ended_is_an_unclean_end(tmp_path) -> None:
    why = ending_of(log_ending_with(tmp_path, "shutdown", outcome="ok", detail="end of stdin"))
    assert why is not None and "does not say" in why


# ------------------------------------------------------------------ real daemons on one log
def daemon_on(tmp_path: Path) -> StdioServerParameters:
    """`armwarden serve` on the log `start_raw_daemon` writes (tmp_path/audit.jsonl)."""
    return serve_params(tmp_path / "audit.jsonl", backend_config(tmp_path, SPEEDUP))


async def safety_of(client: Client) -> dict[str, Any]:
    status = await client.call_tool("get_safety_status", {})
    assert not status.is_error, text_of(status)
    return status.structured_content


def restart_records(path: Path) -> list[dict[str, Any]]:
    """The records of the last run on `path`, from its startup record on."""
    records = records_of(path)
    starts = [i for i, r in enumerate(records) if r["event"] == "startup"]
    return records[starts[-1]:]


@pytest.mark.anyio
async def test_a_start_after_a_kill_mid_motion_is_latched_until_a_human_releases_it(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, SPEEDUP)
    try:
        start_motion(rpc)
    finally:
        kill_at_once(process)
    assert verify_file(audit).ok

    async with Client(stdio_client(daemon_on(tmp_path)), elicitation_callback=approve("bob")) as client:
        status = await safety_of(client)
        assert status["estopped"], status
        event = status["estop_event"]
        assert event["source"] == PREVIOUS_RUN_SOURCE and "without its shutdown record" in event["reason"]
        plan = await client.call_tool("plan_to_joints", {"joint_positions": [0.0, -0.8, 0.0, -2.3, 0.0, 1.6, 0.8]})
        assert plan.is_error and "ESTOP" in text_of(plan), text_of(plan)

        released = await client.call_tool("reset_estop", {})
        assert not released.is_error, text_of(released)
        assert not (await safety_of(client))["estopped"]

    run = restart_records(audit)
    assert run[0]["extra"]["previous_run_unclean"] == event["reason"].split("latched at start: ")[1].split(". Look")[0]
    latched = [r for r in records_of(audit) if r["event"] == "estop"]  # the start's, before its startup record
    assert [r["extra"] for r in latched] == [{"estop_event": event["number"], "source": PREVIOUS_RUN_SOURCE}]
    assert any(r["event"] == "estop_release" and r["operator"] == "bob" for r in run)
    assert run[-1]["event"] == "shutdown" and run[-1]["extra"] == {"arm_stopped": True, "estops_held": []}


@pytest.mark.anyio
async def test_a_start_after_a_clean_shutdown_is_not_latched(tmp_path) -> None:
    process, _rpc, audit = start_raw_daemon(tmp_path, SPEEDUP)
    stop_raw_daemon(process)
    assert records_of(audit)[-1]["extra"] == {"arm_stopped": True, "estops_held": []}

    async with Client(stdio_client(daemon_on(tmp_path))) as client:
        assert not (await safety_of(client))["estopped"]
    assert [r["event"] for r in restart_records(audit)] == ["startup", "tool_call", "shutdown"]


@pytest.mark.anyio
async def test_an_estop_never_released_is_latched_again_after_a_clean_restart(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, SPEEDUP)
    answer = rpc.request("tools/call", {"name": "estop", "arguments": {"reason": "person in the cell"}})
    assert not answer["result"].get("isError"), answer
    stop_raw_daemon(process)
    held = records_of(audit)[-1]["extra"]["estops_held"]
    assert held == [{"number": 1, "source": "estop", "reason": "person in the cell"}]

    async with Client(stdio_client(daemon_on(tmp_path))) as client:
        status = await safety_of(client)
    assert status["estopped"] and "e-stop #1 (estop: person in the cell) latched and never released" in \
        status["estop_event"]["reason"]


@pytest.mark.anyio
async def test_a_start_refused_after_a_kill_does_not_clear_the_latch_for_the_next_one(tmp_path) -> None:
    """Found by review: a start refused after its backend opened (here its HTTP port is busy)
    wrote a clean shutdown record, and the start after it came up unlatched."""
    process, rpc, audit = start_raw_daemon(tmp_path, SPEEDUP)
    try:
        start_motion(rpc)
    finally:
        kill_at_once(process)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        with anyio.fail_after(180):
            refused = await anyio.run_process(
                [*CLI, "serve", "--transport", "http", "--host", "127.0.0.1", "--port", str(busy.getsockname()[1]),
                 "--no-console", "--audit-log", str(audit), "--backend-config", str(backend_config(tmp_path, SPEEDUP)),
                 "--log-level", "WARNING"], cwd=REPO, env=child_env(), check=False)
    stderr = refused.stderr.decode(errors="replace")
    assert refused.returncode == 2 and "Address already in use" in stderr, stderr[-500:]
    assert [e["source"] for e in records_of(audit)[-1]["extra"]["estops_held"]] == [PREVIOUS_RUN_SOURCE]

    async with Client(stdio_client(daemon_on(tmp_path))) as client:
        status = await safety_of(client)
    assert status["estopped"] and status["estop_event"]["source"] == PREVIOUS_RUN_SOURCE, status
