"""The bus layer on python-can's virtual interface: sending, reading, health flags and counters."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import can
import pytest
from can.interfaces.virtual import VirtualBus

from armwarden.backends.can.bus import BusConfig, CanBus, FrameKind, HealthFlag, decode_error_frame, open_interface
from armwarden.backends.can.errors import InvalidFrame
from armwarden.core.errors import BackendError, BackendUnavailable
from tests.backends.can.polling import eventually, unique_channel


@pytest.fixture
def channel() -> str:
    return unique_channel()


@pytest.fixture
def peer(channel: str) -> Iterator[can.BusABC]:
    """Another node on the same virtual bus (the actuators' side)."""
    bus = can.Bus(interface="virtual", channel=channel)
    yield bus
    bus.shutdown()


class Recorder:
    """A frame handler that keeps what it was given and can be told to fail."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []
        self.fail_with: Exception | None = None
        self._lock = threading.Lock()

    def __call__(self, msg: can.Message) -> None:
        failure, self.fail_with = self.fail_with, None
        if failure is not None:
            raise failure
        with self._lock:
            self.frames.append(msg)

    def ids(self) -> list[int]:
        with self._lock:
            return [m.arbitration_id for m in self.frames]


def test_sent_frames_reach_the_other_nodes_and_are_counted_by_kind(channel: str, peer: can.BusABC) -> None:
    with CanBus(BusConfig(channel=channel)) as bus:
        assert bus.send_frame(0x01, bytes(8), extended=False, kind=FrameKind.COMMAND)
        assert bus.send_frame(0x0300FD01, bytes(8), extended=True, kind=FrameKind.MODE)
        health = bus.health()
    first, second = peer.recv(timeout=5), peer.recv(timeout=5)
    assert first is not None and (first.arbitration_id, first.is_extended_id) == (0x01, False)
    assert second is not None and (second.arbitration_id, second.is_extended_id) == (0x0300FD01, True)
    assert (health.frames_sent, health.command_frames_sent, health.sent_by_kind[FrameKind.MODE]) == (2, 1, 1)
    assert health.ok


def test_received_frames_go_to_the_handler(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    with CanBus(BusConfig(channel=channel), recorder) as bus:
        peer.send(can.Message(arbitration_id=0x7, data=b"\x01", is_extended_id=False))
        eventually(lambda: recorder.ids() == [0x7], "the handler received the frame")
        assert bus.health().frames_received == 1


def test_an_invalid_frame_is_counted_and_reading_goes_on(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    recorder.fail_with = InvalidFrame("reply must have 6 or 8 data bytes")
    with CanBus(BusConfig(channel=channel), recorder) as bus:
        peer.send(can.Message(arbitration_id=0x1, data=b"\x00", is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x2, data=b"\x00", is_extended_id=False))
        eventually(lambda: recorder.ids() == [0x2], "the frame after the invalid one was handled")
        health = bus.health()
    assert (health.invalid_frames, health.flags) == (1, HealthFlag.INVALID_FRAME)
    assert health.last_error is not None and "6 or 8 data bytes" in health.last_error


def test_a_failing_handler_is_counted_and_does_not_stop_the_reader(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    recorder.fail_with = RuntimeError("bug in the handler")
    with CanBus(BusConfig(channel=channel), recorder) as bus:
        peer.send(can.Message(arbitration_id=0x1, data=b"", is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x2, data=b"", is_extended_id=False))
        eventually(lambda: recorder.ids() == [0x2], "the frame after the failure was handled")
        health = bus.health()
    assert (health.listener_errors, health.flags) == (1, HealthFlag.LISTENER_ERROR)


def test_bus_off_error_frame_raises_the_bus_off_flag(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    with CanBus(BusConfig(channel=channel), recorder) as bus:
        peer.send(can.Message(arbitration_id=0x40, is_error_frame=True))
        eventually(lambda: HealthFlag.BUS_OFF in bus.health().flags, "BUS_OFF was flagged")
        assert bus.health().error_frames == 1
    assert recorder.ids() == []  # error frames are health, not data


@pytest.mark.parametrize(
    ("class_bits", "flags"),
    [
        (0x040, HealthFlag.BUS_OFF),
        (0x004, HealthFlag.CONTROLLER_ERROR),
        (0x020, HealthFlag.NO_ACK),
        (0x100, HealthFlag.RESTARTED),
        (0x044, HealthFlag.BUS_OFF | HealthFlag.CONTROLLER_ERROR),
        (0x008, HealthFlag.OTHER_ERROR_FRAME),
        (0x000, HealthFlag.OTHER_ERROR_FRAME),
    ],
)
def test_error_frame_classes_decode_into_health_flags(class_bits: int, flags: HealthFlag) -> None:
    assert decode_error_frame(class_bits) == flags


def test_flags_latch_until_cleared_while_counters_stay(channel: str, peer: can.BusABC) -> None:
    with CanBus(BusConfig(channel=channel)) as bus:
        peer.send(can.Message(arbitration_id=0x40, is_error_frame=True))
        eventually(lambda: not bus.health().ok, "the error frame was seen")
        bus.clear_flags()
        health = bus.health()
    assert health.ok and health.error_frames == 1


class FullTxQueueBus(VirtualBus):
    """A virtual bus whose transmit buffer is always full."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("Transmit buffer full")


def test_a_full_transmit_buffer_is_a_tx_queue_overrun(channel: str) -> None:
    with CanBus(BusConfig(channel=channel), bus_factory=lambda cfg: FullTxQueueBus(channel=cfg.channel)) as bus:
        assert not bus.send_frame(0x01, bytes(8), extended=False, kind=FrameKind.COMMAND)
        health = bus.health()
    assert health.flags == HealthFlag.TX_QUEUE_OVERRUN
    assert (health.send_failures, health.frames_sent, health.command_frames_sent) == (1, 0, 0)


class FlakyReceiveBus(VirtualBus):
    """A virtual bus whose first receive fails."""

    failed = False

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self.failed:
            self.failed = True
            raise can.CanOperationError("receive failed")
        return super()._recv_internal(timeout)


def test_a_failing_receive_is_flagged_and_reading_goes_on(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    with CanBus(BusConfig(channel=channel), recorder, bus_factory=lambda cfg: FlakyReceiveBus(channel=cfg.channel)) as bus:
        eventually(lambda: HealthFlag.RECEIVE_ERROR in bus.health().flags, "the receive failure was flagged")
        peer.send(can.Message(arbitration_id=0x5, data=b"", is_extended_id=False))
        eventually(lambda: recorder.ids() == [0x5], "a frame after the failure was handled")


def test_an_interface_python_can_does_not_know_is_unavailable(channel: str) -> None:
    with pytest.raises(BackendUnavailable, match="'no-such-interface' is not available"):
        CanBus(BusConfig(interface="no-such-interface", channel=channel)).open()


def test_sending_on_a_closed_bus_is_refused_and_close_is_idempotent(channel: str) -> None:
    bus = CanBus(BusConfig(channel=channel))
    bus.close()  # before open: nothing to do
    with pytest.raises(BackendError, match="closed"):
        bus.open()
    with pytest.raises(BackendError, match="not open"):
        bus.send_frame(0x01, bytes(8), extended=False, kind=FrameKind.COMMAND)


def test_closing_twice_is_safe(channel: str) -> None:
    bus = CanBus(BusConfig(channel=channel))
    bus.open()
    bus.close()
    bus.close()
    assert not bus.is_open


def test_config_refuses_unknown_keys() -> None:
    with pytest.raises(ValueError, match="bitrate"):
        BusConfig.model_validate({"channel": "can0", "bitrate": 500_000})


def test_open_interface_opens_the_named_virtual_bus(channel: str, peer: can.BusABC) -> None:
    bus = open_interface(BusConfig(channel=channel))
    try:
        bus.send(can.Message(arbitration_id=0x3, data=b"", is_extended_id=False))
        received = peer.recv(timeout=5)
        assert received is not None and received.arbitration_id == 0x3
    finally:
        bus.shutdown()


def test_a_batch_goes_out_in_order_and_is_counted_once_per_frame(channel: str, peer: can.BusABC) -> None:
    frames = [(0x0100FD01 + i, bytes((i,)) * 8, True) for i in range(8)]
    with CanBus(BusConfig(channel=channel)) as bus:
        assert bus.send_frames(frames, FrameKind.COMMAND) == 8
        health = bus.health()
    received = [peer.recv(timeout=5) for _ in frames]
    assert [(m.arbitration_id, bytes(m.data)) for m in received if m is not None] == [(i, d) for i, d, _ in frames]
    assert (health.frames_sent, health.command_frames_sent) == (8, 8)


def test_a_batch_the_driver_refuses_latches_tx_overrun_and_counts_nothing_sent(channel: str) -> None:
    with CanBus(BusConfig(channel=channel), bus_factory=lambda cfg: FullTxQueueBus(channel=cfg.channel)) as bus:
        assert bus.send_frames([(0x01, bytes(8), False), (0x02, bytes(8), False)], FrameKind.COMMAND) == 0
        health = bus.health()
    assert health.flags == HealthFlag.TX_QUEUE_OVERRUN
    assert (health.send_failures, health.frames_sent) == (2, 0)


def test_a_batch_on_a_closed_bus_is_refused(channel: str) -> None:
    bus = CanBus(BusConfig(channel=channel))
    with pytest.raises(BackendError, match="not open"):
        bus.send_frames([(0x01, bytes(8), False)], FrameKind.COMMAND)


def send_after_hand_over(bus: CanBus, peer: can.BusABC, count: int) -> None:
    """Hand reading over, then have the peer send frames 1..count."""
    bus.hand_over_reading()
    for arbitration_id in range(1, count + 1):
        peer.send(can.Message(arbitration_id=arbitration_id, data=bytes(8), is_extended_id=False))


def test_once_reading_is_handed_over_frames_wait_for_drain_and_are_handled_in_order(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    with CanBus(BusConfig(channel=channel), recorder) as bus:
        send_after_hand_over(bus, peer, 5)
        threading.Event().wait(0.2)  # no reader thread any more: nothing is handled meanwhile
        assert recorder.ids() == []
        assert bus.drain() == 5
        assert recorder.ids() == [1, 2, 3, 4, 5]
        assert bus.drain() == 0
        bus.take_back_reading()  # the reader thread again: frames are handled as they come
        peer.send(can.Message(arbitration_id=6, data=bytes(8), is_extended_id=False))
        eventually(lambda: recorder.ids() == [1, 2, 3, 4, 5, 6], "the reader thread handled the new frame")
        assert bus.drain() == 0  # never two readers: drain does nothing while the thread reads


def test_one_drain_handles_at_most_its_limit_and_leaves_the_rest_for_the_next(channel: str, peer: can.BusABC) -> None:
    recorder = Recorder()
    with CanBus(BusConfig(channel=channel), recorder) as bus:
        send_after_hand_over(bus, peer, 10)
        assert bus.drain(limit=4) == 4  # the virtual bus queues a frame as it is sent
        assert recorder.ids() == [1, 2, 3, 4]
        assert bus.drain() == 6
        assert recorder.ids() == list(range(1, 11))


class StallsOnFirst(Recorder):
    """A handler whose first frame takes `stall_s` (a stalled log write, say), noting the thread."""

    def __init__(self, stall_s: float) -> None:
        super().__init__()
        self.stall_s = stall_s
        self.entered = threading.Event()
        self.threads: list[str] = []

    def __call__(self, msg: can.Message) -> None:
        if not self.entered.is_set():
            self.entered.set()
            time.sleep(self.stall_s)
        self.threads.append(threading.current_thread().name)
        super().__call__(msg)


def test_reading_is_not_handed_over_while_the_reader_thread_is_still_handling_a_frame(
        channel: str, peer: can.BusABC) -> None:
    handler = StallsOnFirst(1.5)
    with CanBus(BusConfig(channel=channel), handler) as bus:
        peer.send(can.Message(arbitration_id=1, data=bytes(8), is_extended_id=False))
        assert handler.entered.wait(5)
        with pytest.raises(BackendError, match="did not stop"):
            bus.hand_over_reading()  # two readers would handle the next frames out of order
        peer.send(can.Message(arbitration_id=2, data=bytes(8), is_extended_id=False))
        assert bus.drain() == 0  # not handed over: the caller does not read
        eventually(lambda: handler.ids() == [1], "the stalled frame handled")


def test_taking_reading_back_waits_for_a_drain_under_way_and_later_drains_do_nothing(
        channel: str, peer: can.BusABC) -> None:
    handler = StallsOnFirst(0.5)
    with CanBus(BusConfig(channel=channel), handler) as bus:
        bus.hand_over_reading()
        peer.send(can.Message(arbitration_id=1, data=bytes(8), is_extended_id=False))
        servo = threading.Thread(target=bus.drain, name="servo")
        servo.start()
        assert handler.entered.wait(5)
        bus.take_back_reading()  # as close does after a servo loop that did not stop in time
        for arbitration_id in range(2, 8):
            peer.send(can.Message(arbitration_id=arbitration_id, data=bytes(8), is_extended_id=False))
        servo.join(5)
        eventually(lambda: len(handler.ids()) == 7, "every frame handled")
        assert handler.ids() == list(range(1, 8))
        assert handler.threads[0] == "servo" and "servo" not in handler.threads[1:]
        assert bus.drain() == 0


def test_a_drain_stops_when_its_time_budget_is_spent_and_leaves_the_rest(channel: str, peer: can.BusABC) -> None:
    handler = StallsOnFirst(0.01)  # each call is slow enough for a 1 ms budget to end the drain
    with CanBus(BusConfig(channel=channel), handler) as bus:
        send_after_hand_over(bus, peer, 20)
        assert bus.drain(budget_s=0.001) == 1
        assert bus.drain() == 19
        assert handler.ids() == list(range(1, 21))


def test_a_drain_past_its_budget_still_handles_its_floor_so_a_backlog_cannot_grow(channel: str, peer: can.BusABC) -> None:
    handler = StallsOnFirst(0.01)  # as a host that preempts the drain past its budget on the first frame
    with CanBus(BusConfig(channel=channel), handler) as bus:
        send_after_hand_over(bus, peer, 20)
        assert bus.drain(budget_s=0.001, at_least=6) == 6
        assert bus.drain() == 14
        assert handler.ids() == list(range(1, 21))
