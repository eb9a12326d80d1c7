"""A recorded session for the replay tests: the bundled FR3 policy on the fake arm, driven through
the MCP SDK client as any agent would, and the candidate policies the tests replay it under.

What the session does, in this order (the `SessionLog` fields name the calls the tests look at):

1. ``to_a``: plan_to_pose (0.35, 0.05, 0.45) → ok, executed;
2. ``back_home``: plan_to_joints to the home configuration → ok, executed;
3. ``too_far``: plan_to_pose (2.0, 0, 0.3), out of reach → rejected;
4. ``big_step``: plan_to_joints turning joint 1 by 1.6 rad (over max_joint_step_rad 1.5) → rejected;
5. ``wrist_turn``: plan_to_joints turning joint 7 by 1.0 rad (over soft_joint_step_rad 0.8) → needs_approval;
6. ``fast``: plan_to_pose (0.30, 0.10, 0.45) at velocity_scaling 0.5 (clamped to the cap 0.3) → ok;
7. ``sideways``: plan_cartesian_path 5 cm along +y → ok;
8. ``bad_args``: plan_to_joints with 2 joints → refused before planning (invalid arguments);
9. ``to_b``: plan_to_pose (0.40, -0.15, 0.35) → ok, executed (the last motion: the arm ends there).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from armwarden.policy import apply_overrides, bundled_policy
from tests.helpers import HOME, text_of
from tests.server.harness import approve, arm_harness, policy_with

#: where `to_b` takes the TCP [m]; `B_ZONE` is a keep-out box around it and nothing else the session does
B_TARGET = (0.40, -0.15, 0.35)
B_ZONE = {"name": "new_fixture", "min": [0.37, -0.18, 0.32], "max": [0.43, -0.12, 0.38]}


@dataclass(frozen=True)
class SessionLog:
    path: Path
    plan_ids: dict[str, str | None]  # session step -> plan_id (None: nothing was planned)
    statuses: dict[str, str]  # session step -> the status the daemon answered (or "refused")


async def record_session(tmp_path: Path) -> SessionLog:
    """Run the session (module docstring) and return its audit log."""
    plan_ids: dict[str, str | None] = {}
    statuses: dict[str, str] = {}
    # the bundled policy as it is (not the harness's stall-tolerant default): its digest is recorded
    async with arm_harness(tmp_path, policy_with()) as arm:
        async with arm.client("legacy", approve("replay-test")) as client:
            async def plan(step: str, tool: str, arguments: dict[str, Any], execute: bool = False) -> None:
                result = await client.call_tool(tool, arguments)
                summary = result.structured_content if not result.is_error else None
                plan_ids[step] = summary["plan_id"] if summary else None
                statuses[step] = summary["status"] if summary else "refused"
                if execute:
                    assert summary is not None and summary["status"] == "ok", text_of(result)
                    done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
                    assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)

            def pose(x: float, y: float, z: float, **extra: Any) -> dict[str, Any]:
                return {"position": {"x": x, "y": y, "z": z}, "preview": False, **extra}

            def joints(offsets: dict[int, float]) -> dict[str, Any]:
                return {"joint_positions": [q + offsets.get(i, 0.0) for i, q in enumerate(HOME)], "preview": False}

            await plan("to_a", "plan_to_pose", pose(0.35, 0.05, 0.45), execute=True)
            await plan("back_home", "plan_to_joints", joints({}), execute=True)
            await plan("too_far", "plan_to_pose", pose(2.0, 0.0, 0.3))
            await plan("big_step", "plan_to_joints", joints({0: 1.6}))
            await plan("wrist_turn", "plan_to_joints", joints({6: 1.0}))
            await plan("fast", "plan_to_pose", pose(0.30, 0.10, 0.45, velocity_scaling=0.5))
            await plan("sideways", "plan_cartesian_path",
                       {"waypoints": [{"position": {"x": 0.3069, "y": 0.05, "z": 0.4869}}], "preview": False})
            await plan("bad_args", "plan_to_joints", {"joint_positions": [0.0, 1.0]})
            await plan("to_b", "plan_to_pose", pose(*B_TARGET), execute=True)
    return SessionLog(arm.audit_path, plan_ids, statuses)


def candidate_policy(tmp_path: Path, name: str, **overrides: Any) -> Path:
    """The bundled FR3 policy with dotted-path overrides, written to `tmp_path/name`."""
    document = yaml.safe_load(bundled_policy("fr3").read_text(encoding="utf-8"))
    path = tmp_path / name
    path.write_text(yaml.safe_dump(apply_overrides(document, overrides), sort_keys=False), encoding="utf-8")
    return path


def with_b_zone(tmp_path: Path) -> Path:
    """The bundled policy plus `B_ZONE`: a keep-out box across the path of the session's `to_b`."""
    document = yaml.safe_load(bundled_policy("fr3").read_text(encoding="utf-8"))
    zones = [*document["workspace"]["keep_out"], B_ZONE]
    return candidate_policy(tmp_path, "tighter.yaml", **{"workspace.keep_out": zones})
