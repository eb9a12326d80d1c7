"""The fake backend's fault injections and what it records for tests, in one record its parts share.

The parts of the fake's cell (the fingers, the wrench sensor, the controller manager, ...) read the
injections and add to the records; tests set and read them as attributes of the backend itself
(`fake.fail_stop = True`, `fake.actuation_commands`), which `Knob` forwards to the shared record.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar, overload

T = TypeVar("T")


@dataclass
class FakeKnobs:
    """Fault injections (plain values, changeable at run time) and what the fake records."""

    #: a stop raises and is not delivered
    fail_stop: bool = False
    #: the wrench stops updating, so its stamp stops advancing
    freeze_wrench: bool = False
    #: the joint states' measured torques repeat their last values (a stuck reading)
    freeze_joint_torques: bool = False
    #: the joint states' measured torques read NaN
    nan_joint_torques: bool = False
    #: wrench reads take this long [s]
    stall_wrench_s: float = 0.0
    #: the robot is in an error state (reflex); arm motion is refused until `error_recovery`
    fault: bool = False
    fault_reason: str = ""
    #: width of the object between the fingers [m]; None = exactly what the grasp asks for
    object_width_m: float | None = None
    #: every call that could move something (refused or not) increments this
    actuation_commands: int = 0
    #: the last collision thresholds set (force [N], torque [N·m])
    collision_thresholds: tuple[float, float] | None = None
    #: the force [N] of the last grasp the fingers accepted
    last_grasp_force_n: float | None = None

    def count_actuation(self) -> None:
        """Called first by every call that could move something, before any check refuses it."""
        self.actuation_commands += 1


class HasKnobs(Protocol):
    knobs: FakeKnobs


class Knob(Generic[T]):
    """An attribute of the backend that lives in its `knobs`, so its parts see what a test sets."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, instance: None, owner: type) -> Knob[T]: ...
    @overload
    def __get__(self, instance: HasKnobs, owner: type) -> T: ...
    def __get__(self, instance: HasKnobs | None, owner: type) -> Any:
        return self if instance is None else getattr(instance.knobs, self.name)

    def __set__(self, instance: HasKnobs, value: T) -> None:
        setattr(instance.knobs, self.name, value)


__all__ = ["FakeKnobs", "Knob"]
