"""The ROS 2 backend's camera part: each snapshot is the next image of the camera's topic, with the
subscription owned by the executor thread.

Why subscribe only while someone waits: every image on a subscribed topic is deserialised on the
executor thread, the thread that also carries the joint states and the wrench, so a camera is
subscribed only while a snapshot waits for its next frame. Why on the executor thread: a
subscription destroyed by another thread while the executor walks the node's entities kills the
executor (`InvalidHandle`; found by review, with concurrent snapshots that each subscribed and
unsubscribed from the event loop). So `CameraFeed` creates and destroys its subscription only
in work it hands to `RosBridge.call_soon`, never on the event loop. Concurrent snapshots of one
camera share the subscription, and the first image after they asked answers them all.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import rclpy.qos
import rclpy.subscription
from sensor_msgs.msg import CompressedImage, Image

from armwarden.backends.parts import Cameras
from armwarden.backends.ros2.bridge import RosBridge
from armwarden.backends.ros2.config import CameraConfig
from armwarden.backends.ros2.images import png_from_compressed, png_from_image
from armwarden.backends.values import CameraImage
from armwarden.core.errors import BackendError
from armwarden.handoff import settle_threadsafe

#: added to the slowest camera's own wait for a frame [s]: the snapshot's deadline covers the
#: decoding and the hand-over after the frame arrived
DEADLINE_MARGIN_S = 0.5


@dataclass(eq=False)
class _Waiter:
    """One snapshot waiting for the next image, and the loop its future lives on."""

    loop: asyncio.AbstractEventLoop
    future: asyncio.Future[Any]


class CameraFeed:
    """One camera topic of message type `message_type` (see the module docstring)."""

    def __init__(self, bridge: RosBridge, topic: str, message_type: type, qos: rclpy.qos.QoSProfile) -> None:
        self.topic = topic
        self._bridge = bridge
        self._type = message_type
        self._qos = qos
        self._lock = threading.Lock()  # the waiters and `_queued`: the event loop adds, the executor answers
        self._waiters: list[_Waiter] = []
        self._queued = False  # a `_reconcile` is queued on the executor thread
        self._subscription: rclpy.subscription.Subscription | None = None  # executor thread only

    @property
    def subscribed(self) -> bool:
        """Whether the topic is subscribed now (diagnostics and tests)."""
        return self._subscription is not None

    async def next_message(self, timeout_s: float) -> Any:
        """The first message taken after this call; `TimeoutError` after `timeout_s` [s];
        `BackendError` if the executor is not running (nothing could deliver one)."""
        loop = asyncio.get_running_loop()
        waiter = _Waiter(loop, loop.create_future())
        with self._lock:
            self._waiters.append(waiter)
        try:
            self._reconcile_soon()
            return await asyncio.wait_for(waiter.future, timeout_s)
        finally:
            with self._lock:
                if waiter in self._waiters:
                    self._waiters.remove(waiter)
                idle = not self._waiters
            if idle:  # unsubscribe (on the executor thread) once nobody waits any more
                with contextlib.suppress(BackendError):  # the executor is gone; the node takes it at close
                    self._reconcile_soon()

    def _reconcile_soon(self) -> None:
        """Have the executor thread make the subscription match the waiters (once per change)."""
        with self._lock:
            if self._queued:
                return
            self._queued = True
        try:
            self._bridge.call_soon(self._reconcile)
        except BackendError:
            with self._lock:
                self._queued = False
            raise

    def _reconcile(self) -> None:
        """Executor thread: subscribed while anyone waits, unsubscribed once nobody does."""
        with self._lock:
            self._queued = False
            wanted = bool(self._waiters)
        try:
            node = self._bridge.node
            if wanted and self._subscription is None:
                self._subscription = node.create_subscription(
                    self._type, self.topic, self._on_message, self._qos, callback_group=self._bridge.group)
            elif not wanted and self._subscription is not None:
                subscription, self._subscription = self._subscription, None
                node.destroy_subscription(subscription)
        except Exception as exc:  # the waiters hear why instead of timing out
            self._answer(error=BackendError(f"camera topic {self.topic}: cannot subscribe: {exc}"))
            raise

    def _on_message(self, msg: Any) -> None:
        """Executor thread: answer everyone waiting; unsubscribe on a later turn (not in the
        middle of the executor's walk over the node's subscriptions)."""
        self._answer(msg)
        with contextlib.suppress(BackendError):  # closing: the node takes the subscription with it
            self._reconcile_soon()

    def _answer(self, msg: Any = None, error: BaseException | None = None) -> None:
        with self._lock:
            waiters, self._waiters = self._waiters, []
        for waiter in waiters:
            settle_threadsafe(waiter.loop, waiter.future, msg, error)


class Ros2Cameras(Cameras):
    """The camera part: the configured cameras by name, each fed by its topic. The feeds are made
    at open (`open`), on the bridge that opens; `require_spinning` names a dead executor as the
    cause when no image came."""

    def __init__(self, specs: Mapping[str, CameraConfig], require_spinning: Callable[[], None]) -> None:
        self.specs = dict(specs)
        self.timeout_s = max(spec.timeout_s for spec in self.specs.values()) + DEADLINE_MARGIN_S
        self._require_spinning = require_spinning
        #: the feed of each camera, made at open (diagnostics and tests read `CameraFeed.subscribed`)
        self.feeds: dict[str, CameraFeed] = {}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.specs)

    def open(self, bridge: RosBridge) -> None:
        """Make each camera's feed on `bridge` (subscribed only while a snapshot waits)."""
        qos = rclpy.qos.QoSProfile(depth=1, reliability=rclpy.qos.ReliabilityPolicy.BEST_EFFORT)
        self.feeds = {name: CameraFeed(bridge, spec.topic, CompressedImage if spec.kind == "compressed" else Image, qos)
                      for name, spec in self.specs.items()}

    async def snapshot(self, camera: str) -> CameraImage:
        """The next image on the camera's topic, as PNG."""
        spec = self.specs[camera]
        try:
            msg = await self.feeds[camera].next_message(spec.timeout_s)
        except TimeoutError:
            self._require_spinning()  # a dead executor is why, not the camera
            raise BackendError(f"camera {camera!r}: no image on {spec.topic} within {spec.timeout_s:g} s") from None
        width, height, png = png_from_compressed(msg) if spec.kind == "compressed" else png_from_image(msg)
        return CameraImage(camera, width, height, png, time.monotonic())


__all__ = ["CameraFeed", "Ros2Cameras"]
