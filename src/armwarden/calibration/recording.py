"""The joint states the Guard's contact monitor read, kept per motion and replayed offline.

The calibration's Guard executes through a `RecordingBackend` (its motion runner's backend, not the
Guard's other reads: the checks before a motion read the state too, and a replay that started from
those would drift from the monitor's): while a motion executes, every batch of joint states the
monitor read (`read_joint_states_since`: the samples since its last read) is kept with that motion.
The calibration's tests hold the replayed peaks against the monitor's reported ones. `replay` then
feeds a motion's batches to a fresh observer exactly as the monitor's `JointTorqueContact` does
(same samples, same reads, same skipped intervals), so the residuals it returns are the ones the
monitor would have read with that observer's friction: no friction to fit it, the fitted friction
to see what a monitor with the recommended section would have read on these very samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from armwarden.backends.base import Backend
from armwarden.backends.counting import CountingBackend
from armwarden.core.state import JointState
from armwarden.safety.contact_observer import ContactObserver
from armwarden.safety.contact_source import ContactEstimate, JointTorqueContact

__all__ = ["RecordingBackend", "Replay", "replay"]


class RecordingBackend(CountingBackend):
    """`inner`, with every batch of joint states the monitor read while `motion` is set kept in
    `states[motion]` (one tuple per read)."""

    def __init__(self, inner: Backend) -> None:
        super().__init__(inner)
        #: the motion executing now (None: between motions, nothing is kept)
        self.motion: int | None = None
        self.states: dict[int, list[tuple[JointState, ...]]] = {}

    async def read_joint_states_since(self, stamp: float | None) -> tuple[JointState, ...]:
        states = await self.inner.read_joint_states_since(stamp)
        if self.motion is not None:
            self.states.setdefault(self.motion, []).append(states)
        return states


@dataclass(frozen=True)
class Replay:
    """What an observer read on a motion's samples: per new sample (rows) the joint velocities
    [rad/s] and residuals [N·m]; the largest |residual| per joint over every reading; the largest
    TCP force estimate the monitor would have held against its limit [N]."""

    velocities: np.ndarray
    residuals: np.ndarray
    peaks_nm: np.ndarray
    peak_force_n: float


async def replay(batches: Sequence[tuple[JointState, ...]], observer: ContactObserver, joint_names: Sequence[str],
                 time_scale: float) -> Replay:
    """The monitor's reads (`batches`, one per read) through `observer` (fresh: one per motion,
    as the monitor's) the monitor's way."""
    pending = iter(batches)

    async def read(_since: float | None) -> tuple[JointState, ...]:
        return next(pending)

    contact = JointTorqueContact(read, observer, joint_names, time_scale, max_unobserved_s=math.inf)
    velocities, residuals = [], []
    peaks = np.zeros(len(joint_names))
    peak_force, last_stamp = 0.0, -math.inf
    for batch in batches:
        state = batch[-1]
        reading = await contact.read()
        if not isinstance(reading, ContactEstimate) or not np.all(np.isfinite(reading.external_torques_nm)):
            continue  # the monitor would have stopped the motion: it did not, so this cannot be
        peaks = np.maximum(peaks, np.abs(reading.external_torques_nm))
        if reading.wrench_trusted:
            peak_force = max(peak_force, float(np.linalg.norm(reading.force)))
        if reading.stamp > last_stamp:  # a sample read twice is one sample for the fit
            last_stamp = reading.stamp
            velocities.append(np.asarray(state.velocities, dtype=float))
            residuals.append(np.asarray(reading.external_torques_nm, dtype=float))
    width = len(joint_names)
    return Replay(np.array(velocities).reshape(-1, width), np.array(residuals).reshape(-1, width), peaks, peak_force)
