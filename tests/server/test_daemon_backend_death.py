"""`serve --eval-backend-death`: the evaluation's injected backend death, on a real daemon.

Evaluation only: accepted for a simulated backend alone (refused, exit 2 before anything is served,
for ROS 2 by name and for a CAN config that may reach hardware by the built backend's own word),
written into the start-up record, and then SIGUSR2 makes the backend die through its real failure
path: recorded as injected, then latched and recorded as the backend's own fault.
"""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path
from typing import Any

import anyio
import pytest
import yaml
from mcp import Client, StdioServerParameters

from armwarden.evaluation.targets import DEFAULT_CAN_CONFIG
from tests.helpers import CLI, REPO, child_env, records_of, text_of, wait_for_record

FLAG = "--eval-backend-death"


def _can_config(tmp_path: Path, interface: str | None, simulate: bool) -> Path:
    """examples/can_sim.yaml on another bus `interface`, or without its `simulate` section."""
    document = yaml.safe_load(DEFAULT_CAN_CONFIG.read_text(encoding="utf-8"))
    if interface is not None:
        document["bus"]["interface"] = interface
    if not simulate:
        document.pop("simulate")
    path = tmp_path / "can.yaml"
    path.write_text(yaml.safe_dump(document), encoding="utf-8")
    return path


REFUSALS = {
    "ros2": (lambda tmp: ["--backend", "ros2"], "not 'ros2', which may drive a real arm"),
    "can_on_socketcan": (lambda tmp: ["--backend", "can", "--backend-config", str(_can_config(tmp, "socketcan", True))],
                         "its bus interface is 'socketcan', not 'virtual'"),
    "can_without_its_emulator": (lambda tmp: ["--backend", "can", "--backend-config", str(_can_config(tmp, None, False))],
                                 "it has no `simulate` section"),
}


@pytest.mark.parametrize("case", sorted(REFUSALS))
def test_the_injected_death_is_refused_for_a_backend_that_may_drive_a_real_arm(tmp_path, case) -> None:
    extra, expected = REFUSALS[case]
    audit = tmp_path / "audit.jsonl"
    result = subprocess.run([*CLI, "serve", FLAG, "--audit-log", str(audit), *extra(tmp_path)], cwd=REPO,
                            env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert "refusing to start" in result.stderr and expected in result.stderr, result.stderr
    assert result.stdout == ""  # nothing was served
    assert not audit.exists() or not any(r["event"] == "startup" for r in records_of(audit))


async def _safety(client: Client) -> dict[str, Any]:
    result = await client.call_tool("get_safety_status", {})
    assert not result.is_error, text_of(result)
    return result.structured_content


@pytest.mark.anyio
async def test_sigusr2_makes_the_fake_control_thread_die_latched_and_recorded(tmp_path) -> None:
    audit = tmp_path / "audit.jsonl"
    params = StdioServerParameters(command=CLI[0], args=[*CLI[1:], "serve", FLAG, "--audit-log", str(audit)],
                                   env=child_env(), cwd=str(REPO))
    async with Client(params, mode="legacy") as client:
        assert not (await _safety(client))["estopped"]
        (startup,) = [r for r in records_of(audit) if r["event"] == "startup"]
        assert startup["extra"]["eval_backend_death"] is True
        os.kill(startup["extra"]["pid"], signal.SIGUSR2)
        with anyio.fail_after(30):
            while True:  # the control thread dies at its next tick; the e-stop latches on its report
                status = await _safety(client)
                if status["estopped"]:
                    break
                await anyio.sleep(0.05)
        assert status["estop_event"]["source"] == "backend_fault", status
        assert "the control thread stopped (InjectedBackendDeath" in status["estop_event"]["reason"], status
        planned = await client.call_tool("plan_to_joints", {"joint_positions": [0.0] * 7})
        assert planned.is_error and "ESTOP" in text_of(planned), text_of(planned)
    records = await wait_for_record(audit, lambda r: r["event"] == "shutdown")
    events = [r["event"] for r in records]
    assert events.index("eval_backend_death") < events.index("backend_fault"), events
