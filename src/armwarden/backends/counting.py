"""A wrapper that counts every actuation command reaching a backend.

Evidence for "a refusal moves nothing": tests and `scripts/eval_safety.py` put it between the
Guard and the real backend and assert that refused requests added no command. It forwards
everything unchanged.
"""

from __future__ import annotations

from typing import Any

#: the Backend methods that can move or change the robot
ACTUATING_METHODS = (
    "execute", "gripper_move", "gripper_grasp", "gripper_home", "switch_controllers",
    "set_collision_thresholds", "error_recovery",
)


class CountingBackend:
    """Wraps a backend: every actuating call is recorded (by method name) before it is forwarded."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self.actuations: list[str] = []
        self.stops = 0

    def __getattr__(self, name: str) -> Any:
        attribute = getattr(self._inner, name)
        if name in ACTUATING_METHODS:
            async def counted(*args: Any, **kwargs: Any) -> Any:
                self.actuations.append(name)
                return await attribute(*args, **kwargs)

            return counted
        if name == "stop":
            async def stop() -> None:
                self.stops += 1
                await attribute()

            return stop
        return attribute
