"""What the console shows, read from the Guard and the audit log: never anything that moves.

`StateFeed.snapshot` gathers the live state (joints against their limits, TCP, wrench, gripper),
the safety status, the motion status and the open approval requests into one plain dict, which
the pages render and `/console/api/state` serves as JSON. A robot state that cannot be read
(stale, missing) is shown as that refusal, not as old numbers. `live_picture` draws the arm as it
stands with the plan preview renderer; `audit_status` verifies the log's chain on a worker
thread, again only when the file has changed, and then parses only the records appended since
(`verify_appended`: the bytes verified before must still hash the same, or all is verified again).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import anyio
import numpy as np

from armwarden.approval.board import PendingRequest
from armwarden.audit import VerifiedPrefix, verify_appended
from armwarden.core.errors import SafetyRefusal
from armwarden.core.trajectory import JointTrajectory
from armwarden.guard import Guard
from armwarden.safety.limits import EnvelopeReport

__all__ = ["AuditStatus", "StateFeed", "request_view"]

AUDIT_TAIL = 30


@dataclass(frozen=True)
class AuditStatus:
    """The result of `audit verify` on the daemon's log, and the file state it was computed for."""

    ok: bool
    records: int
    detail: str
    signature: tuple[int, int]
    verified: VerifiedPrefix | None = None  # where the next verification may resume


def request_view(request: PendingRequest) -> dict[str, Any]:
    """One approval request as plain data (no digest: the approval code stands for it)."""
    report = request.plan.report
    return {
        "id": request.request_id,
        "plan_id": request.plan_id,
        "code": request.code,
        "prompt": request.prompt,
        "expires_at": request.plan.expires_at_wall,
        "duration_s": round(request.plan.trajectory.duration_s, 3),
        "peak_velocity_ratio": round(report.max_joint_velocity_ratio, 3),
        "largest_travel_rad": round(report.max_joint_travel_rad, 4),
        "tcp_path_m": round(report.tcp_path_length_m, 4),
        "violations": [{"code": c, "severity": s, "detail": d} for c, s, d in request.violations],
        "answer": request.answer,
        "operator": request.operator,
        "requester": request.requester,
        "self_approved": request.self_approved,
    }


class StateFeed:
    """Reads for the console pages; one per console."""

    def __init__(self, guard: Guard) -> None:
        from armwarden.preview.render import PlanPreviewer

        self.guard = guard
        #: the plan preview renderer, with its own scene cache (used on the planning thread only)
        self._previewer = PlanPreviewer(guard.planning.envelope.limits)
        self._audit_status: AuditStatus | None = None
        self._verify_lock = anyio.Lock()

    async def robot(self) -> dict[str, Any]:
        """Joints against limits, TCP, wrench, gripper; or {"error": why} when unreadable."""
        guard = self.guard
        try:
            state = await guard.robot_state()
        except SafetyRefusal as exc:
            return {"error": f"{exc.code}: {exc}"}
        limits = guard.policy.robot.joint_limits
        joints = []
        for name, q, dq in zip(state.joint_names, state.joint_positions, state.joint_velocities, strict=True):
            lo, hi = limits[name].min, limits[name].max
            joints.append({"name": name, "position": q, "velocity": dq, "min": lo, "max": hi,
                           "fraction": min(1.0, max(0.0, (q - lo) / (hi - lo))) if hi > lo else 0.5})
        return {
            "error": None,
            "joints": joints,
            "tcp": state.tcp_pose.model_dump(),
            "frame": state.frame_id,
            "wrench": None if state.wrench is None else state.wrench.model_dump(),
            "gripper": None if state.gripper is None else state.gripper.model_dump(),
        }

    def safety(self) -> dict[str, Any]:
        status = self.guard.safety_status()
        motion = self.guard.motion_status()
        return {
            "estopped": status.estopped,
            "event": None if status.estop_event is None else status.estop_event.model_dump(),
            "force_latched": status.force_violation_latched,
            "dry_run": status.dry_run,
            "faults": list(status.faults),
            "audit_ok": status.audit_ok,
            "audit_error": status.audit_error,
            "last_violation": None if status.last_violation is None else status.last_violation.model_dump(),
            "executing": motion.executing,
            "plan_id": motion.plan_id,
            "progress": motion.progress,
            "last_result": None if motion.last_result is None else motion.last_result.status,
        }

    def approvals(self) -> list[dict[str, Any]]:
        return [request_view(r) for r in self.guard.approvals.live(self.guard.latch.generation)]

    async def snapshot(self) -> dict[str, Any]:
        return {"robot": await self.robot(), "safety": self.safety(), "approvals": self.approvals()}

    async def live_picture(self) -> bytes | None:
        """Top and side views of the arm as it stands, against the workspace and keep-out zones."""
        guard = self.guard
        try:
            state = await guard.readings.joint_state()
        except SafetyRefusal:
            return None
        q = np.asarray(state.positions, dtype=float)
        standing = JointTrajectory(tuple(guard.policy.robot.joint_names), np.array([0.0]), q.reshape(1, -1))
        return await self._picture(standing, EnvelopeReport(violations=()), "live")

    async def plan_picture(self, request: PendingRequest) -> bytes | None:
        """The plan's preview, as the plan summary carried it: drawn from the stored trajectory and report."""
        plan = request.plan
        return await self._picture(plan.trajectory, plan.report, plan.status)

    async def _picture(self, trajectory: JointTrajectory, report: EnvelopeReport, status: str) -> bytes | None:
        """Drawn on the planning thread: the planning model's Pinocchio data is used only there."""
        robot, previewer = self.guard.planning.robot, self._previewer
        return await self.guard.planning_flow.on_thread(lambda: previewer.render(robot, trajectory, report, status=status))

    async def audit_tail(self, n: int = AUDIT_TAIL) -> list[dict[str, Any]]:
        audit = self.guard.audit
        if audit is None or audit.closed:
            return []
        return list(reversed(await audit.tail_async(n)))  # newest first

    async def audit_status(self) -> AuditStatus | None:
        """`audit verify` of the daemon's log, recomputed only when the file changed."""
        audit = self.guard.audit
        if audit is None:
            return None
        path = audit.path
        async with self._verify_lock:
            try:
                st = os.stat(path)
            except OSError as exc:
                return AuditStatus(False, 0, f"cannot read the log: {exc.strerror}", (0, 0))
            signature = (st.st_size, st.st_mtime_ns)
            cached = self._audit_status
            if cached is not None and cached.signature == signature:
                return cached
            from armwarden.audit import hmac_key_from_env

            previous = cached.verified if cached is not None else None
            report, verified = await anyio.to_thread.run_sync(lambda: verify_appended(path, hmac_key_from_env(), previous))
            detail = ("intact" if report.ok else f"BROKEN at line {report.first_bad_line}: {report.reason}")
            self._audit_status = AuditStatus(report.ok, report.records, detail, signature, verified)
            return self._audit_status
