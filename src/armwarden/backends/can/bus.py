"""A CAN bus on python-can: open any interface from config, read on a Notifier, watch health.

One `CanBus` owns one python-can bus and the Notifier thread that reads it — until the owner
takes reading over (`hand_over_reading`): a servo loop then reads what has arrived at the start
of every tick (`drain`), so a fault frame that reached the bus before a tick is handled before
that tick commands, however late the reader thread would have been scheduled under load; one
reader at a time, so frames are handled in the order they arrived. Every received data frame
goes to the owner's handler on the reading thread; the handler raises `InvalidFrame` for a
malformed frame (counted, INVALID_FRAME) and any other exception is a handler bug (counted,
logged, LISTENER_ERROR) — neither stops the reader, so state updates never silently end. Error
frames are decoded into health flags (SocketCAN reports bus-off only this way; python-can's
`virtual` interface never produces them, the emulator injects them). A send that the driver
refuses (`CanOperationError`, e.g. "Transmit buffer full") is a TX_QUEUE_OVERRUN, and a
successful send only means the driver took the frame: the actuator's reply is the acknowledgement.

Flags latch until `clear_flags` (a human reset); counters only grow. `health()` is a snapshot.
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType, TracebackType

import can
from pydantic import BaseModel, ConfigDict, Field

from armwarden.backends.can.errors import InvalidFrame
from armwarden.core.errors import BackendError, BackendUnavailable

logger = logging.getLogger(__name__)

#: how long the reader waits in one `recv` [s]; bounds how long `close` waits for it
READ_TIMEOUT_S = 0.05
#: the most frames one `drain` handles (the servo loop also gives it a time budget; the rest wait a tick)
DRAIN_LIMIT = 256
#: at most one log line per this many seconds for a repeating reader error [s]
ERROR_LOG_PERIOD_S = 1.0


class BusConfig(BaseModel):
    """Which CAN interface to open (strict: unknown keys are errors)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    interface: str = Field("virtual", min_length=1, description="python-can interface: socketcan on hardware, virtual in simulation")
    channel: str = Field(min_length=1, description="interface channel, e.g. can0, or any name shared by virtual buses")
    bitrate_bps: int = Field(1_000_000, gt=0, description="nominal bit rate [bit/s] (RobStride: 1 Mbit/s)")
    receive_own_messages: bool = Field(False, description="also receive the frames this bus sends")
    send_timeout_s: float = Field(0.002, ge=0, le=1, description="how long a send may wait for room in the TX queue [s]")


class HealthFlag(enum.Flag):
    """What went wrong on the bus (latched)."""

    BUS_OFF = enum.auto()
    CONTROLLER_ERROR = enum.auto()
    NO_ACK = enum.auto()
    RESTARTED = enum.auto()
    OTHER_ERROR_FRAME = enum.auto()
    TX_QUEUE_OVERRUN = enum.auto()
    INVALID_FRAME = enum.auto()
    LISTENER_ERROR = enum.auto()
    RECEIVE_ERROR = enum.auto()


NO_FLAGS = HealthFlag(0)
#: SocketCAN error-class bits of an error frame's id -> health flag
ERROR_CLASSES: Mapping[int, HealthFlag] = MappingProxyType({
    0x040: HealthFlag.BUS_OFF,
    0x004: HealthFlag.CONTROLLER_ERROR,
    0x020: HealthFlag.NO_ACK,
    0x100: HealthFlag.RESTARTED,
})


def decode_error_frame(arbitration_id: int) -> HealthFlag:
    """The health flags an error frame's class bits stand for (other classes: OTHER_ERROR_FRAME)."""
    flags = NO_FLAGS
    rest = arbitration_id
    for bit, flag in ERROR_CLASSES.items():
        if arbitration_id & bit:
            flags |= flag
            rest &= ~bit
    if rest or not flags:
        flags |= HealthFlag.OTHER_ERROR_FRAME
    return flags


class FrameKind(str, enum.Enum):
    """What a sent frame does, for counting actuation at the bus."""

    COMMAND = "command"  # an impedance command: tracking, hold or damping (MIT command, RobStride type 1)
    MODE = "mode"  # enable, disable/stop, MIT special frames
    PARAMETER = "parameter"  # parameter reads and writes
    QUERY = "query"  # pings


@dataclass(frozen=True)
class BusHealth:
    """A snapshot of the bus: latched flags and counters since open."""

    flags: HealthFlag
    frames_sent: int
    sent_by_kind: Mapping[FrameKind, int]
    send_failures: int
    frames_received: int
    error_frames: int
    invalid_frames: int
    listener_errors: int
    last_error: str | None

    @property
    def ok(self) -> bool:
        return self.flags == NO_FLAGS

    @property
    def command_frames_sent(self) -> int:
        return self.sent_by_kind.get(FrameKind.COMMAND, 0)


#: called on the reader thread for every received data frame; raises `InvalidFrame` for a malformed one
FrameHandler = Callable[[can.Message], None]
#: opens the python-can bus a `BusConfig` names (tests substitute one with injected failures)
BusFactory = Callable[[BusConfig], can.BusABC]


def open_interface(config: BusConfig) -> can.BusABC:
    """The python-can bus `config` names (python-can's own exceptions pass through)."""
    return can.Bus(
        interface=config.interface, channel=config.channel, bitrate=config.bitrate_bps,
        receive_own_messages=config.receive_own_messages,
    )


class _Counters:
    def __init__(self) -> None:
        self.flags = NO_FLAGS
        self.frames_sent = 0
        self.sent_by_kind = dict.fromkeys(FrameKind, 0)
        self.send_failures = 0
        self.frames_received = 0
        self.error_frames = 0
        self.invalid_frames = 0
        self.listener_errors = 0
        self.last_error: str | None = None


class _Listener(can.Listener):
    """Feeds the owner's handler; never lets an exception escape to the Notifier."""

    def __init__(self, owner: CanBus) -> None:
        self._owner = owner

    def on_message_received(self, msg: can.Message) -> None:
        self._owner._received(msg)

    def on_error(self, exc: Exception) -> None:
        self._owner._reader_failed(exc)

    def stop(self) -> None:
        """Nothing to release (the owner closes the bus)."""


class CanBus:
    """One python-can bus, its reader thread and its health (see the module docstring)."""

    def __init__(self, config: BusConfig, handler: FrameHandler | None = None, *, bus_factory: BusFactory = open_interface) -> None:
        self.config = config
        self._handler = handler
        self._bus_factory = bus_factory
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._send_lock = threading.Lock()
        self._count_lock = threading.Lock()
        self._counters = _Counters()
        self._last_error_log = float("-inf")
        self._closed = False
        # held while frames are handled off the reader thread (`drain`) and while reading changes
        # hands or the bus closes: never two readers, never a drain on a closed bus
        self._read_lock = threading.Lock()

    # ---------------------------------------------------------------- lifecycle
    @property
    def is_open(self) -> bool:
        return self._bus is not None and not self._closed

    def open(self) -> None:
        """Open the interface and start reading; `BackendUnavailable` if python-can has no such
        interface here, `BackendError` if it cannot be opened. Opening twice does nothing."""
        if self._bus is not None:
            return
        if self._closed:
            raise BackendError(f"CAN bus {self.config.channel} is closed")
        cfg = self.config
        try:
            bus = self._bus_factory(cfg)
        except can.CanInterfaceNotImplementedError as exc:
            raise BackendUnavailable(f"CAN interface {cfg.interface!r} is not available: {exc}") from exc
        except (can.CanError, OSError, ValueError) as exc:
            raise BackendError(f"cannot open CAN interface {cfg.interface!r} channel {cfg.channel!r}: {exc}") from exc
        self._bus = bus
        self._notifier = can.Notifier(bus, [_Listener(self)], timeout=READ_TIMEOUT_S)
        logger.info("CAN bus %s:%s open at %d bit/s", cfg.interface, cfg.channel, cfg.bitrate_bps)

    def close(self) -> None:
        """Stop reading and release the interface. Safe twice and before `open`."""
        with self._read_lock:  # a drain under way finishes first
            if self._closed:
                return
            self._closed = True
            if self._notifier is not None:
                self._notifier.stop(timeout=10 * READ_TIMEOUT_S)
            if self._bus is not None:
                with self._send_lock:
                    self._bus.shutdown()
                logger.info("CAN bus %s:%s closed", self.config.interface, self.config.channel)

    def __enter__(self) -> CanBus:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # ---------------------------------------------------------------- who reads
    def hand_over_reading(self) -> None:
        """Stop the reader thread: from now on the caller reads, with `drain` (see the module
        docstring). Frames that arrive meanwhile wait in the interface; none is lost.
        `BackendError` if the reader thread does not stop in time (a handler stalled): two
        readers would handle frames out of order, so reading is not handed over."""
        with self._read_lock:
            notifier = self._notifier
            if notifier is None:
                return
            notifier.stop(timeout=10 * READ_TIMEOUT_S)
            # python-can keeps its reader threads in `_readers`; stop() returns when the wait ends,
            # stopped or not
            if any(isinstance(r, threading.Thread) and r.is_alive() for r in getattr(notifier, "_readers", ())):
                raise BackendError(f"CAN bus {self.config.channel}: the reader thread did not stop within "
                                   f"{10 * READ_TIMEOUT_S:g} s; reading is not handed over")
            self._notifier = None

    def take_back_reading(self) -> None:
        """Start the reader thread again (the caller no longer drains: its loop stopped or died).
        A drain under way finishes first; later drains do nothing."""
        with self._read_lock:
            if self._bus is not None and not self._closed and self._notifier is None:
                self._notifier = can.Notifier(self._bus, [_Listener(self)], timeout=READ_TIMEOUT_S)

    def drain(self, limit: int = DRAIN_LIMIT, budget_s: float | None = None, at_least: int = 0) -> int:
        """Handle, on the calling thread, the frames that have arrived — at most `limit`, and no
        more once `budget_s` has passed and `at_least` have been handled (the rest wait for the
        next call); how many. The floor keeps a drain that a loaded host preempted from ending
        after one frame tick after tick: the backlog, and a fault frame queued behind it, would
        then wait ever longer. Only while reading is handed over (two readers would handle
        frames out of order)."""
        with self._read_lock:
            bus = self._bus
            if bus is None or self._closed or self._notifier is not None:
                return 0
            deadline = None if budget_s is None else time.perf_counter() + budget_s
            handled = 0
            while handled < limit:
                try:
                    msg = bus.recv(timeout=0)
                except Exception as exc:  # as the reader thread: latched, never raised into the servo loop
                    self._reader_failed(exc)
                    break
                if msg is None:
                    break
                self._received(msg)
                handled += 1
                if deadline is not None and handled >= at_least and time.perf_counter() > deadline:
                    break
            return handled

    # ---------------------------------------------------------------- sending (any thread)
    def send(self, message: can.Message, kind: FrameKind) -> bool:
        """Send `message`; False (and TX_QUEUE_OVERRUN) if the driver refused it. `BackendError`
        if the bus is not open. Thread-safe."""
        return self._send_messages((message,), kind) == 1

    def send_frame(self, arbitration_id: int, data: bytes, *, extended: bool, kind: FrameKind) -> bool:
        """`send` a data frame built from an id and data bytes."""
        return self.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=extended), kind)

    def send_frames(self, frames: Sequence[tuple[int, bytes, bool]], kind: FrameKind) -> int:
        """Send data frames `(arbitration_id, data, extended)` in order, under one lock (a servo
        tick's commands go out together); how many the driver took (each refusal latches
        TX_QUEUE_OVERRUN and the rest are still tried)."""
        return self._send_messages(
            [can.Message(arbitration_id=i, data=data, is_extended_id=extended) for i, data, extended in frames], kind)

    def _send_messages(self, messages: Sequence[can.Message], kind: FrameKind) -> int:
        sent = 0
        with self._send_lock:
            bus = self._bus
            if bus is None or self._closed:
                raise BackendError(f"CAN bus {self.config.channel} is not open")
            timeout = self.config.send_timeout_s
            for message in messages:
                try:
                    bus.send(message, timeout=timeout)
                except (can.CanOperationError, can.CanTimeoutError) as exc:
                    self._count_send_failure(exc)
                    continue
                sent += 1
        with self._count_lock:
            self._counters.frames_sent += sent
            self._counters.sent_by_kind[kind] += sent
        return sent

    # ---------------------------------------------------------------- health
    def health(self) -> BusHealth:
        with self._count_lock:
            c = self._counters
            return BusHealth(
                flags=c.flags, frames_sent=c.frames_sent, sent_by_kind=MappingProxyType(dict(c.sent_by_kind)),
                send_failures=c.send_failures, frames_received=c.frames_received, error_frames=c.error_frames,
                invalid_frames=c.invalid_frames, listener_errors=c.listener_errors, last_error=c.last_error,
            )

    @property
    def flags(self) -> HealthFlag:
        """The latched health flags (what `health().flags` says, without copying the counters)."""
        with self._count_lock:
            return self._counters.flags

    def clear_flags(self) -> None:
        """Clear the latched flags (a human reset, once the cause is gone); counters stay."""
        with self._count_lock:
            self._counters.flags = NO_FLAGS
            self._counters.last_error = None

    def note_invalid_frame(self, reason: str) -> None:
        """Count a frame the owner found invalid outside the handler (e.g. an unexpected sender)."""
        self._flag(HealthFlag.INVALID_FRAME, reason, counter="invalid_frames")

    # ---------------------------------------------------------------- the reader thread
    def _received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            flags = decode_error_frame(msg.arbitration_id)
            with self._count_lock:
                self._counters.error_frames += 1
            self._flag(flags, f"error frame 0x{msg.arbitration_id:X}")
            return
        with self._count_lock:
            self._counters.frames_received += 1
        if self._handler is None:
            return
        try:
            self._handler(msg)
        except InvalidFrame as exc:
            self.note_invalid_frame(f"invalid frame 0x{msg.arbitration_id:X}: {exc}")
        except Exception as exc:  # a handler bug must not stop the reader: count it, latch, go on
            self._flag(HealthFlag.LISTENER_ERROR, f"frame handler failed: {exc!r}", counter="listener_errors", exc=exc)

    def _reader_failed(self, exc: Exception) -> None:
        self._flag(HealthFlag.RECEIVE_ERROR, f"receive failed: {exc!r}", counter="listener_errors", exc=exc)

    def _count_send_failure(self, exc: Exception) -> None:
        self._flag(HealthFlag.TX_QUEUE_OVERRUN, f"send refused: {exc}", counter="send_failures")

    def _flag(self, flags: HealthFlag, reason: str, *, counter: str | None = None, exc: Exception | None = None) -> None:
        with self._count_lock:
            c = self._counters
            c.flags |= flags
            c.last_error = reason
            if counter is not None:
                setattr(c, counter, getattr(c, counter) + 1)
        now = time.monotonic()
        if now - self._last_error_log >= ERROR_LOG_PERIOD_S:  # a flood of bad frames must not flood the log
            self._last_error_log = now
            logger.error("CAN bus %s: %s", self.config.channel, reason, exc_info=exc)


__all__ = [
    "DRAIN_LIMIT",
    "ERROR_CLASSES",
    "NO_FLAGS",
    "BusConfig",
    "BusFactory",
    "BusHealth",
    "CanBus",
    "FrameHandler",
    "FrameKind",
    "HealthFlag",
    "decode_error_frame",
    "open_interface",
]
