"""Measured joint torques (`sensor_msgs/JointState.effort`) in the ROS 2 backend's joint-state
cache, on plain message stand-ins: taken by name into the policy's order only when the config
declares them, in the same sample (one stamp) as the positions; a message whose `effort` misses a
joint or carries NaN passes NaN on for that joint (the monitor fails closed on it), never zero and
never the last value. Runs without ROS."""

from __future__ import annotations

import math
from types import SimpleNamespace as Msg

import pytest

from armwarden.backends import parse_backend_config
from armwarden.backends.ros2.config import Config
from armwarden.backends.ros2.state import JointStateCache
from armwarden.core.errors import ConfigurationError

NAN = float("nan")


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def joint_msg(t: float, names: list[str], positions: list[float], efforts: list[float]) -> Msg:
    stamp = Msg(sec=int(t), nanosec=round((t - int(t)) * 1e9))
    return Msg(header=Msg(stamp=stamp), name=names, position=positions, velocity=[0.0] * len(names), effort=efforts)


def cache(clock: Clock | None = None, *, efforts: bool = True) -> JointStateCache:
    return JointStateCache("/joint_states", ("a", "b"), ("ros_a", "ros_b"), 0.5, clock or Clock(), efforts=efforts)


def test_declared_efforts_are_matched_by_name_into_policy_order() -> None:
    states = cache()
    states.accept(joint_msg(1.0, ["ros_b", "other", "ros_a"], [2.0, 9.0, 1.0], [-20.5, 3.0, 4.25]))
    state = states.fresh()
    assert state.efforts is not None and state.efforts.tolist() == [4.25, -20.5]


def test_efforts_belong_to_the_same_sample_and_stamp_as_the_positions() -> None:
    clock = Clock()
    states = cache(clock)
    states.accept(joint_msg(1.0, ["ros_a", "ros_b"], [0.0, 0.0], [1.0, 2.0]))
    clock.now += 0.2
    states.accept(joint_msg(1.2, ["ros_a", "ros_b"], [0.1, 0.1], [3.0, 4.0]))
    state = states.fresh()
    assert state.stamp == clock.now and state.positions.tolist() == [0.1, 0.1]
    assert state.efforts is not None and state.efforts.tolist() == [3.0, 4.0]


def test_a_message_without_efforts_when_declared_gives_nan_efforts_not_zeros() -> None:
    states = cache()
    states.accept(joint_msg(1.0, ["ros_a", "ros_b"], [0.0, 0.0], []))
    state = states.fresh()
    assert state.efforts is not None and all(math.isnan(e) for e in state.efforts)


def test_a_short_effort_array_gives_nan_for_the_joints_it_misses() -> None:
    states = cache()
    states.accept(joint_msg(1.0, ["ros_a", "ros_b"], [0.0, 0.0], [7.0]))
    efforts = states.fresh().efforts
    assert efforts is not None and efforts[0] == 7.0 and math.isnan(efforts[1])


def test_a_nan_effort_is_passed_on_and_never_replaced_by_the_last_value() -> None:
    clock = Clock()
    states = cache(clock)
    states.accept(joint_msg(1.0, ["ros_a", "ros_b"], [0.0, 0.0], [5.0, 6.0]))
    clock.now += 0.01
    states.accept(joint_msg(1.01, ["ros_a", "ros_b"], [0.0, 0.0], [NAN, 6.5]))
    state = states.fresh()
    assert state.efforts is not None and math.isnan(state.efforts[0]) and state.efforts[1] == 6.5
    assert state.stamp == clock.now  # a NaN effort does not drop the sample: its positions are good


def test_efforts_are_read_only_like_the_positions() -> None:
    states = cache()
    states.accept(joint_msg(1.0, ["ros_a", "ros_b"], [0.0, 0.0], [1.0, 2.0]))
    efforts = states.fresh().efforts
    assert efforts is not None
    with pytest.raises(ValueError, match="read-only"):
        efforts[0] = 0.0


def test_undeclared_efforts_are_none_even_when_the_message_carries_them() -> None:
    states = cache(efforts=False)
    states.accept(joint_msg(1.0, ["ros_a", "ros_b"], [0.0, 0.0], [1.0, 2.0]))
    assert states.fresh().efforts is None


def test_the_config_declares_no_efforts_by_default_and_takes_a_boolean() -> None:
    assert Config().joint_states.efforts is False
    config = parse_backend_config("ros2", {"joint_states": {"efforts": True}})
    assert isinstance(config, Config) and config.joint_states.efforts is True
    with pytest.raises(ConfigurationError, match=r"joint_states\.efforts"):
        parse_backend_config("ros2", {"joint_states": {"efforts": "maybe"}})
