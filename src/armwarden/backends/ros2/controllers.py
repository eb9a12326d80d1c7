"""The ROS 2 backend's service parts: the controller manager (list/switch) and error recovery (a Trigger).

Kept apart from motion because they share nothing with it but the bridge: a call waits (bounded
by the part's deadline) for its service, then for the answer on the executor thread
(`RosBridge.result`). A switch names
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

from armwarden.backends.parts import Controllers, ErrorRecovery
from armwarden.backends.ros2.bridge import RosBridge
from armwarden.backends.ros2.config import ControllerManagerConfig
from armwarden.backends.ros2.endpoints import Endpoints
from armwarden.backends.values import ControllerInfo
from armwarden.core.errors import BackendError

#: how often a call looks whether its service is ready [s]
SERVICE_POLL_S = 0.01


@dataclass
class ServiceCalls:
    """Service calls through the backend's bridge and the clients it made at open."""

    bridge: RosBridge
    endpoints: Endpoints

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


class Ros2Controllers(Controllers):
    """The controller manager part: its list and switch services, the switch limited to `manager`'s allowlist."""

    def __init__(self, services: ServiceCalls, manager: ControllerManagerConfig) -> None:
        self._services, self._manager = services, manager

    async def list(self) -> list[ControllerInfo]:
        response = await self._services.call(self._services.endpoints.list_controllers, ListControllers.Request(),
                                             "list controllers", self.timeout_s)
        return [ControllerInfo(c.name, c.type, c.state) for c in response.controller]

    async def switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        """A strict switch of allowlisted controllers; any other name refuses the whole switch."""
        manager = self._manager
        refused = sorted({*activate, *deactivate} - set(manager.allowlist))
        if refused:
            allowed = ", ".join(manager.allowlist) or "none"
            raise BackendError(f"controller(s) {', '.join(refused)} are not in the ros2 backend's allowlist "
                               f"(allowed: {allowed}); nothing was switched")
        request = SwitchController.Request(activate_controllers=list(activate), deactivate_controllers=list(deactivate),
                                           strictness=SwitchController.Request.STRICT)
        response = await self._services.call(self._services.endpoints.switch_controller, request, "switch controllers",
                                             self.timeout_s)
        if not response.ok:
            raise BackendError(f"the controller manager refused the switch: {response.message or 'no reason given'}")


class Ros2ErrorRecovery(ErrorRecovery):
    """The error recovery part: the arm driver's Trigger service that clears its latched error."""

    def __init__(self, services: ServiceCalls) -> None:
        self._services = services

    async def recover(self) -> None:
        response = await self._services.call(self._services.endpoints.error_recovery, Trigger.Request(),
                                             "error recovery", self.timeout_s)
        if not response.success:
            raise BackendError(f"error recovery failed: {response.message or 'no reason given'}")


__all__ = ["Ros2Controllers", "Ros2ErrorRecovery", "ServiceCalls"]
