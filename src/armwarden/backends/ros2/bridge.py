"""rclpy inside the daemon: a private context, one node, one executor thread, asyncio bridging.

Why a private `Context` with `SignalHandlerOptions.NO`: with rclpy's default signal handling,
SIGINT shuts every context down and SIGTERM is swallowed, but the daemon handles its own signals
(and must stop the arm on them). A `SingleThreadedExecutor` spins on a thread of its own, so ROS
callbacks never wait for the event loop and the event loop never blocks on DDS. Single, not
multi-threaded: every callback here is short and never waits for another, and rclpy's
`MultiThreadedExecutor` (Jazzy) costs several times the CPU per message and, on a loaded host,
fell hundreds of milliseconds behind a 100 Hz joint-state stream — long enough to look like a
dead cell (measured: docs/benchmarks.md, "ROS 2 executor"). `close` shuts the
executor down and *joins* its thread before destroying the node: a thread left spinning aborts
the process at exit.

Who owns the rclpy entities: the executor thread. The executor walks the node's subscriptions,
timers and clients on every turn, and one destroyed by another thread in the middle of that walk
kills it (`InvalidHandle: cannot use Destroyable because destruction was requested`; found by
review: concurrent camera snapshots, each subscribing and unsubscribing from the event loop, did
it, and the daemon then served stale data while reporting itself healthy). So the endpoints that
live as long as the node are made by `start`'s `setup` before the thread spins, and destroyed
with the node after it has been joined; anything made or destroyed in between goes through
`call_soon`, which runs it on the executor thread between two turns.

The executor thread's death is never silent: an exception out of `spin`, or `spin` returning
before `close` (the context shut down under it), is logged and handed to `on_death` (the backend
reports a latched fault). Nor is its hang: a timer on the executor bumps `heartbeats` every
`HEARTBEAT_PERIOD_S`, and the backend's watchdog, on a thread of its own, finds a count that
stops (a callback that blocks holds up every other, the heartbeat's too).

rclpy futures are not awaitable by asyncio; `result` bridges one with `add_done_callback` (called
on an executor thread) and `loop.call_soon_threadsafe` (see `armwarden.handoff`), guarded against
a loop that has closed meanwhile.
"""

from __future__ import annotations

import asyncio
import logging
import os
import threading
from collections.abc import Callable
from typing import Any

import rclpy
import rclpy.callback_groups
import rclpy.context
import rclpy.executors
import rclpy.node
import rclpy.task
import rclpy.utilities
from rclpy.signals import SignalHandlerOptions

from armwarden.backends.ros2.dds import DdsSettings, dds_settings
from armwarden.core.errors import BackendError
from armwarden.handoff import settle_threadsafe

logger = logging.getLogger(__name__)

#: how long `close` waits for the executor to stop and its thread to end [s]
SHUTDOWN_TIMEOUT_S = 5.0
#: period of the executor's heartbeat timer [s] (its hang deadline: `stall_deadline_s` of it)
HEARTBEAT_PERIOD_S = 0.02


#: builds the executor from the bridge's context
ExecutorFactory = Callable[..., rclpy.executors.Executor]
#: told (on the dying executor thread) that it ended before `close`: the exception, or None if it returned
DeathListener = Callable[[BaseException | None], object]


def domain_from_environment() -> int:
    """ROS_DOMAIN_ID from the environment (0 when unset, as ROS itself does)."""
    return dds_settings(None, os.environ).domain_id


class RosBridge:
    """One node in a private context, spun on its own thread. `start` then `close` (twice is safe)."""

    def __init__(self, node_name: str, domain_id: int | None,
                 executor_factory: ExecutorFactory = rclpy.executors.SingleThreadedExecutor) -> None:
        self.node_name = node_name
        self.domain_id = domain_id
        #: the domain and discovery range in use, once started (named in "nothing arrived" errors)
        self.dds: DdsSettings | None = None
        self._executor_factory = executor_factory  # another only to measure it (scripts/bench.py ros2)
        self._context: rclpy.context.Context | None = None
        self._node: rclpy.node.Node | None = None
        self._executor: rclpy.executors.Executor | None = None
        self._thread: threading.Thread | None = None
        self._closed = threading.Event()
        #: one group for every endpoint (callbacks guard their own state: they run on the executor
        #: thread while the event loop and stopping threads read it)
        self.group = rclpy.callback_groups.ReentrantCallbackGroup()
        #: told when the executor thread ends before `close` (see the module docstring)
        self.on_death: DeathListener | None = None
        #: turns of the heartbeat timer so far (the executor's progress; see the module docstring)
        self.heartbeats = 0

    @property
    def node(self) -> rclpy.node.Node:
        if self._node is None:
            raise BackendError("the ROS node is not running")
        return self._node

    def start(self, setup: Callable[[], None] | None = None) -> None:
        """Make the context, the node and the executor, call `setup` (it creates the endpoints that
        live as long as the node, before anything spins), then spin on the executor thread."""
        dds = dds_settings(self.domain_id, os.environ)
        dds.apply(os.environ)  # the default range, where rcl reads it (process-wide, before any init)
        self.dds = dds
        context = rclpy.context.Context()
        rclpy.init(context=context, domain_id=dds.domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self._context = context
        try:
            self._node = rclpy.create_node(self.node_name, context=context)
            self._executor = self._executor_factory(context=context)
            self._executor.add_node(self._node)
            self._node.create_timer(HEARTBEAT_PERIOD_S, self._beat, callback_group=self.group)
            if setup is not None:
                setup()
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._spin, name="armwarden-ros2-executor", daemon=True)
        self._thread.start()
        logger.info("ros2: node %s started: %s", self.node_name, dds.describe())

    def _beat(self) -> None:
        """Executor thread: one more turn (read by the backend's watchdog)."""
        self.heartbeats += 1

    def _spin(self) -> None:
        executor = self._executor
        assert executor is not None
        error: BaseException | None = None
        try:
            executor.spin()
        except BaseException as exc:  # while closing: the context shut down under it; else the thread died
            error = exc
        if self._closed.is_set():
            return
        if error is not None:
            logger.error("ros2: the executor thread failed", exc_info=error)
        else:
            logger.error("ros2: the executor stopped spinning before close (its context was shut down)")
        listener = self.on_death
        if listener is not None:
            try:
                listener(error)
            except Exception:
                logger.exception("ros2: reporting the executor thread's death failed")

    def call_soon(self, work: Callable[[], None]) -> None:
        """Run `work` on the executor thread between two turns (any thread may ask): where rclpy
        entities are made and destroyed while the node lives. `work` must be quick; an exception
        from it is logged, never raised into the executor (it would end the thread). `BackendError`
        if the executor is not spinning (nothing would run it)."""
        executor = self._executor
        if executor is None or not self.spinning:
            raise BackendError("the ROS executor thread is not running")

        def guarded() -> None:
            try:
                work()
            except Exception:
                logger.exception("ros2: work on the executor thread failed")

        executor.create_task(guarded)

    @property
    def spinning(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive() and not self._closed.is_set()

    def close(self) -> None:
        """Stop the executor, join its thread, destroy the node, shut the context down."""
        if self._closed.is_set():
            return
        self._closed.set()
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=SHUTDOWN_TIMEOUT_S)
        if self._thread is not None:
            self._thread.join(timeout=SHUTDOWN_TIMEOUT_S)
            if self._thread.is_alive():
                logger.error("ros2: the executor thread did not end within %s s", SHUTDOWN_TIMEOUT_S)
        if self._node is not None:
            self._node.destroy_node()
        if self._context is not None:
            rclpy.utilities.try_shutdown(context=self._context)

    async def result(self, future: rclpy.task.Future, timeout_s: float | None) -> Any:
        """Await an rclpy future from asyncio; `TimeoutError` after `timeout_s` [s] (None: no
        deadline — the caller bounds the wait). The rclpy
        future is left alone on timeout or cancellation (its late result is dropped)."""
        loop = asyncio.get_running_loop()
        waiter: asyncio.Future[Any] = loop.create_future()
        # an error that lands after the awaiter gave up (a node destroyed at close) is not "never retrieved"
        waiter.add_done_callback(lambda f: f.cancelled() or f.exception())

        def done(finished: rclpy.task.Future) -> None:  # the executor thread, or this one if already done
            error = finished.exception()
            if error is None and finished.cancelled():
                error = BackendError("the ROS request was cancelled")
            if not loop.is_closed():
                settle_threadsafe(loop, waiter, None if error is not None else finished.result(), error)

        future.add_done_callback(done)
        return await asyncio.wait_for(waiter, timeout_s)


__all__ = ["HEARTBEAT_PERIOD_S", "DeathListener", "ExecutorFactory", "RosBridge", "domain_from_environment"]
