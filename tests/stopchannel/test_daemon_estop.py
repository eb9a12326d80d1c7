"""The stop paths that bypass MCP, against a real `armwarden serve` subprocess on 127.0.0.1:
the stop channel (`--estop-port`), SIGUSR1, and the `armwarden estop` command."""

from __future__ import annotations

import http.client
import json
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import anyio
import pytest

from armwarden.safety.refusals import OVERALL_BURST, OVERALL_RECORDS_PER_S
from armwarden.stopchannel import EStopUnauthorized, send_estop
from tests.server.harness import MotionStarted
from tests.server.http_daemon import CLI, HOST, REPO, Daemon, child_env, free_port, http_daemon, session

pytestmark = pytest.mark.anyio

ROTATING_SOURCES = 300


def records_of(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def external_estops(daemon: Daemon) -> list[dict[str, Any]]:
    return [r for r in records_of(daemon.audit) if r["event"] == "estop" and r.get("tool") is None]


def wait_for(predicate, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.05)


class ChannelDaemon:
    def __init__(self, daemon: Daemon, estop_port: int) -> None:
        self.daemon, self.estop_url = daemon, f"http://{HOST}:{estop_port}/estop"


@pytest.fixture
def channel_daemon(tmp_path: Path) -> Iterator[ChannelDaemon]:
    estop_port = free_port()
    with http_daemon(tmp_path, speedup=0.5, extra_args=["--estop-port", str(estop_port)]) as daemon:
        yield ChannelDaemon(daemon, estop_port)


async def safety_status(daemon: Daemon) -> dict[str, Any]:
    http, client = session(daemon, daemon.observer_token, "legacy")
    async with http, client:
        return (await client.call_tool("get_safety_status", {})).structured_content


async def reset(daemon: Daemon) -> None:
    from tests.server.harness import approve

    http, client = session(daemon, daemon.operator_token, "legacy", approve())
    async with http, client:
        result = await client.call_tool("reset_estop", {})
        assert not result.is_error, result


async def test_the_channel_latches_and_stops_with_no_mcp_session_open(channel_daemon: ChannelDaemon) -> None:
    daemon = channel_daemon.daemon
    answer = await anyio.to_thread.run_sync(lambda: send_estop(channel_daemon.estop_url, daemon.observer_token, "hand on the button"))
    assert answer["estopped"] is True and answer["event"] >= 1
    status = await safety_status(daemon)
    assert status["estopped"] is True
    assert status["estop_event"]["number"] == answer["event"] and status["estop_event"]["source"] == "stop_channel"
    wait_for(lambda: len(external_estops(daemon)) == 1)
    record = external_estops(daemon)[0]
    assert record["outcome"] == "latched" and record["principal"] == "bob"
    assert record["arguments"] == {"reason": "hand on the button"}
    await reset(daemon)


async def test_the_channel_refuses_a_request_without_a_valid_token(channel_daemon: ChannelDaemon) -> None:
    with pytest.raises(EStopUnauthorized):
        await anyio.to_thread.run_sync(lambda: send_estop(channel_daemon.estop_url, "aw_not-a-token"))
    assert (await safety_status(channel_daemon.daemon))["estopped"] is False
    assert external_estops(channel_daemon.daemon) == []

    def refusals() -> list[dict[str, Any]]:
        return [r for r in records_of(channel_daemon.daemon.audit) if r["event"] == "stop_channel_refused"]

    wait_for(lambda: len(refusals()) == 1)
    assert refusals()[0]["extra"]["status"] == 401 and refusals()[0]["outcome"] == "refused"


async def test_a_channel_stop_during_execute_plan_aborts_that_call_and_latches(channel_daemon: ChannelDaemon) -> None:
    daemon = channel_daemon.daemon
    http, client = session(daemon, daemon.operator_token, "legacy")
    async with http, client:
        state = (await client.call_tool("get_robot_state", {})).structured_content
        goal = list(state["joint_positions"])
        goal[0] += 0.6  # a couple of seconds at half speed
        plan = (await client.call_tool("plan_to_joints", {"joint_positions": goal})).structured_content
        assert plan["status"] == "ok", plan
        started = MotionStarted()
        outcome: dict[str, Any] = {}
        async with anyio.create_task_group() as group:
            async def execute() -> None:
                outcome["result"] = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]},
                                                           progress_callback=started)

            group.start_soon(execute)
            with anyio.fail_after(20):
                await started.event.wait()
            answer = await anyio.to_thread.run_sync(lambda: send_estop(channel_daemon.estop_url, daemon.operator_token))
        report = outcome["result"].structured_content
        assert report["status"] == "aborted", report
        final = (await client.call_tool("get_robot_state", {})).structured_content["joint_positions"]
        assert abs(final[0] - goal[0]) > 0.05  # stopped short of the goal
        status = (await client.call_tool("get_safety_status", {})).structured_content
        assert status["estopped"] is True and status["estop_event"]["number"] == answer["event"]
    await reset(daemon)


async def test_sigusr1_latches_and_stops(channel_daemon: ChannelDaemon) -> None:
    daemon = channel_daemon.daemon
    daemon.process.send_signal(signal.SIGUSR1)
    wait_for(lambda: len(external_estops(daemon)) == 1)
    record = external_estops(daemon)[0]
    assert record["outcome"] == "latched" and record["principal"] == "signal:SIGUSR1"
    status = await safety_status(daemon)
    assert status["estopped"] is True and status["estop_event"]["source"] == "signal"
    await reset(daemon)


def test_the_estop_command_stops_through_the_channel_and_by_pid(channel_daemon: ChannelDaemon, tmp_path: Path) -> None:
    daemon = channel_daemon.daemon
    token_file = tmp_path / "token"
    token_file.write_text(daemon.observer_token + "\n", encoding="utf-8")
    by_url = subprocess.run([*CLI, "estop", "--url", channel_daemon.estop_url, "--token-file", str(token_file)],
                            cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=60)
    assert by_url.returncode == 0, by_url.stderr
    by_pid = subprocess.run([*CLI, "estop", "--pid", str(daemon.process.pid)], cwd=REPO, env=child_env(),
                            capture_output=True, text=True, timeout=60)
    assert by_pid.returncode == 0, by_pid.stderr
    wait_for(lambda: len(external_estops(daemon)) == 2)
    assert sorted(r["principal"] for r in external_estops(daemon)) == ["bob", "signal:SIGUSR1"]


def test_an_estop_port_without_tokens_is_refused_at_start_up(tmp_path: Path) -> None:
    result = subprocess.run([*CLI, "serve", "--estop-port", str(free_port()), "--audit-log", str(tmp_path / "a.jsonl")],
                            cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "--estop-port needs --auth-tokens" in result.stderr


async def test_an_mcp_estop_holds_the_arm_as_its_request_is_read(channel_daemon: ChannelDaemon) -> None:
    daemon = channel_daemon.daemon
    http, client = session(daemon, daemon.observer_token, "legacy")
    async with http, client:
        result = await client.call_tool("estop", {"reason": "over http"})
        assert result.structured_content["estopped"] is True
    records = records_of(daemon.audit)
    held = [r for r in records if r["event"] == "stop_on_receipt"]
    call = [r for r in records if r["event"] == "tool_call" and r["tool"] == "estop"]
    assert len(held) == 1 and held[0]["principal"] == "bob" and held[0]["outcome"] == "stopped"
    assert len(call) == 1 and held[0]["seq"] < call[0]["seq"]
    await reset(daemon)


def refuse_from(port: int, source: str) -> int:
    """POST /estop with a wrong token from the loopback address `source`; the answer's status."""
    connection = http.client.HTTPConnection(HOST, port, timeout=30, source_address=(source, 0))
    try:
        connection.request("POST", "/estop", body=b"", headers={"Authorization": "Bearer aw_wrong"})
        return connection.getresponse().status
    finally:
        connection.close()


def refused_stops_accounted(daemon: Daemon) -> int:
    """Refused stop-channel requests the log accounts for: each record, the ones it says were left
    out before it, and the counts reported on their own."""
    records = records_of(daemon.audit)
    one_by_one = [r for r in records if r["event"] == "stop_channel_refused"]
    counted = [r for r in records if r["event"] == "refusals_left_out" and r["extra"]["door"] == "stop_channel"]
    return len(one_by_one) + sum(r["extra"]["not_reported_since_last"] for r in one_by_one) + \
        sum(r["extra"]["count"] for r in counted)


def test_refused_stops_from_rotating_sources_are_all_counted_in_few_records(channel_daemon: ChannelDaemon) -> None:
    """Found by an outside review (issue 24, review 2, item 5c): 300 refused stops from 300
    loopback addresses wrote 296 records (the per-host limit alone does not hold against
    rotation) and the counts of the hosts pushed out of the table went to stderr only."""
    daemon, port = channel_daemon.daemon, int(channel_daemon.estop_url.rsplit(":", 1)[1].split("/")[0])
    started = time.monotonic()
    for i in range(ROTATING_SOURCES):
        assert refuse_from(port, f"127.77.{i // 250}.{i % 250 + 1}") == 401
    elapsed = time.monotonic() - started

    wait_for(lambda: refused_stops_accounted(daemon) == ROTATING_SOURCES, timeout_s=30.0)
    records = [r for r in records_of(daemon.audit) if r["event"] in ("stop_channel_refused", "refusals_left_out")]
    per_source = [r for r in records if r["event"] == "stop_channel_refused" or r["extra"]["source"] is not None]
    assert len(per_source) <= OVERALL_BURST + OVERALL_RECORDS_PER_S * elapsed + 1
