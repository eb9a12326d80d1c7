"""Putting a Guard together: the one place that wires policy, models, backend and audit log.

The daemon, the test harness, `scripts/eval_safety.py` and `scripts/gen_docs.py` all build their
Guard here, so what the tests exercise is what `armwarden serve` runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from armwarden.backends import create_backend, load_backend_config
from armwarden.guard import Guard
from armwarden.guard.planning import Previewer
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.robot import build_robot

if TYPE_CHECKING:
    from pydantic import BaseModel

    from armwarden.audit import AuditLog
    from armwarden.backends.base import Backend
    from armwarden.core.trajectory import JointTrajectory
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel
    from armwarden.safety.limits import EnvelopeReport

def plan_previewer() -> Previewer:
    """The plan preview renderer the daemon attaches to every plan summary: one `PlanPreviewer`
    (which caches the static scene) per policy's limits, rebuilt only if the runtime model's
    limits are replaced. Called on the planning thread only, like the robot model it uses."""
    from armwarden.preview.render import PlanPreviewer

    previewers: list[PlanPreviewer] = []  # the current one; a list so the closure can replace it

    def preview(runtime: RuntimeModel, trajectory: JointTrajectory, report: EnvelopeReport) -> bytes | None:
        limits = runtime.envelope.limits
        if not previewers or previewers[0].limits is not limits:
            previewers[:] = [PlanPreviewer(limits)]
        return previewers[0].render(runtime.robot, trajectory, report)

    return preview


def build_backend(
    name: str, policy: Policy, *, robot: RobotModel | None = None,
    config: BaseModel | dict[str, Any] | None = None, config_path: str | Path | None = None,
) -> Backend:
    """Backend `name` for `policy` (not opened). `config` (a mapping or the backend's `Config`)
    or `config_path` (a `--backend-config` file) give its options; neither: the defaults."""
    if config is not None and config_path is not None:
        raise ValueError("give the backend options either as config or as config_path, not both")
    if config_path is not None:
        config = load_backend_config(name, config_path)
    return create_backend(name, robot if robot is not None else build_robot(policy), policy, config)


def build_guard(
    policy: Policy,
    backend: Backend,
    audit: AuditLog | None,
    *,
    previewer: Previewer | None = None,
    runtime: RuntimeModel | None = None,
    robot: RobotModel | None = None,
) -> Guard:
    """The Guard for `policy` in front of `backend`, recording to `audit` (None: no audit log).

    `runtime` (the planning thread's model) and `robot` (the loop-side state model) are built
    from the policy unless given; `previewer` draws plan previews (None: plans carry none).
    """
    return Guard(
        policy,
        runtime if runtime is not None else load_runtime_model(policy),
        robot if robot is not None else build_robot(policy),
        backend,
        audit=audit,
        previewer=previewer,
    )


__all__ = ["Previewer", "build_backend", "build_guard", "plan_previewer"]
