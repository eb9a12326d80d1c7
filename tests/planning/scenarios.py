"""Scenes the detour tests share: the runtime model with extra keep-out zones, a pillar in the
way of a base rotation (a detour exists), and a goal hemmed in by a zone (plans into or out of it
fail the final check)."""

from __future__ import annotations

import dataclasses

import numpy as np

from armwarden.preflight import RuntimeModel
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import Box
from tests.helpers import READY
from tests.safety.dense_oracle import DenseOracle

#: planning budget of the scenarios that expect a detour: the policy's cap, so that a detour found in
#: tens of milliseconds on a quiet machine is still found when CI's other lane starves this one
#: (the budget itself is tested with explicit, smaller budgets)
SCENARIO_BUDGET_S = 2.0


def with_zones(runtime: RuntimeModel, *zones: Box, budget_s: float = SCENARIO_BUDGET_S, detours: bool = True) -> RuntimeModel:
    """The runtime model with `zones` added to the policy's and its own detour planner (or none)."""
    from armwarden.planning.around import DetourPlanner

    limits = dataclasses.replace(runtime.envelope.limits, keep_out=runtime.envelope.limits.keep_out + tuple(zones))
    envelope = Envelope(runtime.robot, limits)
    planner = DetourPlanner(runtime.planner, envelope, budget_s) if detours else None
    return dataclasses.replace(runtime, envelope=envelope, detours=planner)


def base_turn(angle: float) -> np.ndarray:
    """The ready pose with the base (joint 1) turned by `angle` [rad]."""
    return READY + np.array([angle, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])


#: a thin pillar where the hand passes when the base turns from -0.6 to +0.6 rad at the ready pose
PILLAR = Box.of("pillar", [0.28, -0.02, 0.0], [0.34, 0.02, 0.50])
PILLAR_START, PILLAR_GOAL = base_turn(-0.6), base_turn(0.6)


def pillar_at(runtime: RuntimeModel, angle: float) -> Box:
    """A 6 × 4 cm pillar, 50 cm tall, around where the TCP is with the base turned by `angle` from ready."""
    centre = runtime.robot.tcp_pose(base_turn(angle)).position
    return Box.of("pillar", [centre[0] - 0.03, centre[1] - 0.02, 0.0], [centre[0] + 0.03, centre[1] + 0.02, 0.50])


def hemmed_block(runtime: RuntimeModel, gap_m: float = 0.0001) -> Box:
    """A block `gap_m` below the padded hand and fingers at the ready pose. With the default 0.1 mm
    the ready pose itself is clear, but every motion into or out of it sweeps the fingers into the
    block (the sweep allowance of a plan's first and last sample, half the motion bound of the
    densest sampling interval, is about 0.3 mm with the bundled 1 cm resolution): a search for a
    way out runs out of budget."""
    robot, limits = runtime.robot, runtime.envelope.limits
    p0, p1 = robot.body_points(robot.joint_frames(READY[None]))
    by_link = getattr(limits, "padding_by_link_m", {})  # fingers may carry less padding than the arm
    hand = [i for i, capsule in enumerate(robot.capsules) if "hand" in capsule.link or "finger" in capsule.link]
    lowest = min(min(p0[0, i, 2], p1[0, i, 2]) - robot.capsule_radii[i]
                 - by_link.get(robot.capsules[i].link, limits.link_padding_m) for i in hand)
    return Box.of("block", [0.15, -0.12, 0.0], [0.45, 0.12, lowest - gap_m])


def oracle_for(model: RuntimeModel) -> DenseOracle:
    """The independent dense checker with the model's zones and self-collision pairs."""
    return DenseOracle(model.robot, model.envelope.limits, [tuple(p) for p in model.envelope.bodies.pairs])
