"""The gripper flow: gripper_move, gripper_grasp, gripper_home.

Order: audit writable → e-stop latch → arguments (`safety.checks.check_gripper`) → one gripper
action at a time → dry run → the backend command. A gripper call cancelled mid-action (client
cancel, disconnect, timeout) stops arm and gripper before the cancellation goes on.
"""

from __future__ import annotations

from collections.abc import Awaitable
from typing import Literal

import anyio

from armwarden.backends.values import GripperResult
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard.gates import GuardState
from armwarden.results import GripperResultModel
from armwarden.safety import checks

GripperTool = Literal["gripper_move", "gripper_grasp", "gripper_home"]


class GripperFlow:
    """Runs the gripper tools through the Guard's gates; `busy` while a gripper action runs."""

    def __init__(self, state: GuardState) -> None:
        self._state = state
        self.busy = False

    async def run(self, tool: GripperTool, width_m: float | None, force_n: float | None, speed_mps: float | None,
                  epsilon_inner_m: float, epsilon_outer_m: float) -> GripperResultModel:
        state = self._state
        state.require_audit(tool)
        stop_epoch = state.backend.stop_epoch  # decided now: any stop from here on keeps the fingers still ...
        state.require_not_estopped(tool)  # ... and an e-stop latched before it refuses
        speed = checks.check_gripper(state.policy, width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)
        if self.busy:
            raise SafetyRefusal(RefusalCode.BUSY, "another gripper action is running")
        if state.dry_run:
            return GripperResultModel(status="dry_run", width_m=None, is_grasped=None, detail="dry run: nothing moved")
        self.busy = True
        try:
            call = self._command(tool, width_m, force_n, speed, epsilon_inner_m, epsilon_outer_m, stop_epoch)
            try:
                result = await state.readings.backend_call(tool.replace("_", " "), call)
            except anyio.get_cancelled_exc_class():
                with anyio.CancelScope(shield=True):
                    await state.stopper.stop_motion()
                raise
        finally:
            self.busy = False
        return GripperResultModel(
            status="succeeded" if result.success else "failed", width_m=result.width_m, is_grasped=result.is_grasped,
            detail=result.detail or ("done" if result.success else "the gripper action did not succeed"),
        )

    def _command(self, tool: GripperTool, width_m: float | None, force_n: float | None, speed_mps: float,
                 epsilon_inner_m: float, epsilon_outer_m: float, stop_epoch: int) -> Awaitable[GripperResult]:
        """The backend command for `tool`. The tool schemas require width (and force for a grasp);
        a caller that bypasses them is refused, not guessed for."""
        backend = self._state.backend
        if tool == "gripper_home":
            return backend.gripper_home(stop_epoch=stop_epoch)
        if width_m is None:
            raise SafetyRefusal(RefusalCode.INVALID, f"{tool} needs width_m")
        if tool == "gripper_move":
            return backend.gripper_move(width_m, speed_mps, stop_epoch=stop_epoch)
        if force_n is None:
            raise SafetyRefusal(RefusalCode.INVALID, "gripper_grasp needs force_n")
        return backend.gripper_grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m, stop_epoch=stop_epoch)
