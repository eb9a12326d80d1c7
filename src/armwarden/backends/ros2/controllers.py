"""The ROS 2 backend's service calls: controller_manager list/switch and the error-recovery Trigger.

Kept apart from motion because they share nothing with it but the bridge: a call waits (bounded)
for its service, then for the answer on the executor thread (`RosBridge.result`). A switch names
only allowlisted controllers; any other name is refused before a request is sent, so a client
cannot deactivate the trajectory controller behind the Guard's back.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import anyio
import rclpy.client
from controller_manager_msgs.srv import ListControllers, SwitchController
from std_srvs.srv import Trigger

from armwarden.backends.ros2.bridge import RosBridge
from armwarden.backends.ros2.config import ControllerManagerConfig
from armwarden.backends.ros2.endpoints import Endpoints
from armwarden.backends.values import ControllerInfo
from armwarden.core.errors import BackendError

#: how often a call looks whether its service is ready [s]
SERVICE_POLL_S = 0.01


@dataclass
class Ros2Controllers:
    """The service calls, through the backend's bridge and the clients it made at open."""

    bridge: RosBridge
    endpoints: Endpoints
    manager: ControllerManagerConfig | None

    async def call(self, client: rclpy.client.Client | None, request: Any, what: str, timeout_s: float) -> Any:
        """`request`'s answer, or `BackendError` naming the service that was not there or did not answer."""
        assert client is not None
        deadline = time.monotonic() + timeout_s
        while not client.service_is_ready():
            if time.monotonic() > deadline:
                raise BackendError(f"the service {client.srv_name} is not available (waited {timeout_s:g} s)")
            await anyio.sleep(SERVICE_POLL_S)
        try:
            return await self.bridge.result(client.call_async(request), max(0.0, deadline - time.monotonic()))
        except TimeoutError:
            raise BackendError(f"{what}: {client.srv_name} did not answer within {timeout_s:g} s") from None

    async def list(self, timeout_s: float) -> list[ControllerInfo]:
        response = await self.call(self.endpoints.list_controllers, ListControllers.Request(), "list controllers",
                                   timeout_s)
        return [ControllerInfo(c.name, c.type, c.state) for c in response.controller]

    async def switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...], timeout_s: float) -> None:
        """A strict switch of allowlisted controllers; any other name refuses the whole switch."""
        manager = self.manager
        assert manager is not None
        refused = sorted({*activate, *deactivate} - set(manager.allowlist))
        if refused:
            allowed = ", ".join(manager.allowlist) or "none"
            raise BackendError(f"controller(s) {', '.join(refused)} are not in the ros2 backend's allowlist "
                               f"(allowed: {allowed}); nothing was switched")
        request = SwitchController.Request(activate_controllers=list(activate), deactivate_controllers=list(deactivate),
                                           strictness=SwitchController.Request.STRICT)
        response = await self.call(self.endpoints.switch_controller, request, "switch controllers", timeout_s)
        if not response.ok:
            raise BackendError(f"the controller manager refused the switch: {response.message or 'no reason given'}")

    async def recover(self, timeout_s: float) -> None:
        response = await self.call(self.endpoints.error_recovery, Trigger.Request(), "error recovery", timeout_s)
        if not response.success:
            raise BackendError(f"error recovery failed: {response.message or 'no reason given'}")


__all__ = ["Ros2Controllers"]
