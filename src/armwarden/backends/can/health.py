"""The CAN actuators' fault conditions, looked at every servo tick and before enabling.

An actuator that has left a command unanswered for `rx_timeout_s` (RX timeout), fault bits in its
feedback or a RobStride fault frame, a temperature above `temperature_limit_c`, invalid frames, an
actuator that left run mode (once enabled), and the bus's latched flags (bus-off and other error
frames, TX overrun, reader errors). The backend damps every joint on any of them.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

from armwarden.backends.can import robstride as rs
from armwarden.backends.can.actuators import Actuator
from armwarden.backends.can.bus import NO_FLAGS, CanBus, HealthFlag
from armwarden.backends.can.config import Config


def fault_conditions(everyone: Sequence[Actuator], state_lock: threading.Lock, bus: CanBus | None, config: Config,
                     *, enabled: bool, now: float) -> list[str]:
    """Every fault condition present at `now` (monotonic [s]), naming the joint (or the bus)."""
    problems: list[str] = []
    limit = config.temperature_limit_c
    with state_lock:
        for a in everyone:
            if a.unanswered_since is not None and now - a.unanswered_since > config.rx_timeout_s:
                problems.append(f"{a.label}: no reply for {1000 * (now - a.unanswered_since):.0f} ms (RX timeout)")
            if a.fault_bits:
                problems.append(f"{a.label}: fault {', '.join(a.fault_bits)}")
            if a.fault_frames:
                problems.append(f"{a.label}: fault frame {', '.join(a.fault_frames)}")
            if a.temperature_c is not None and a.temperature_c > limit:
                problems.append(f"{a.label}: over-temperature {a.temperature_c:.1f} °C (limit {limit:g} °C)")
            if a.invalid_frames:
                problems.append(f"{a.label}: {a.invalid_frames} invalid frame(s)")
            if enabled and a.mode is not None and a.mode is not rs.MotorMode.RUN:
                problems.append(f"{a.label}: left run mode ({a.mode.name})")
        attributed = any(a.invalid_frames for a in everyone)
    if bus is not None:
        flags = bus.flags
        if attributed:
            flags &= ~HealthFlag.INVALID_FRAME
        if flags != NO_FLAGS:
            names = ", ".join(f.name or "?" for f in HealthFlag if f in flags)
            problems.append(f"all joints: CAN bus {names}")
    return problems


__all__ = ["fault_conditions"]
