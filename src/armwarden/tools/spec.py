"""What one tool is, as data: its name, group, MCP hints, who may call it, how it stops, what
approval it needs, what it returns and which backend capability and call it needs.

Everything the daemon treats a tool by is here, so a new tool is one record (plus its MCP face
and its Guard handler), and no module keeps a parallel list of names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel

#: the policy's tool groups, in the order of the tool reference (docs/tools.md)
ToolGroup = Literal["introspect", "perception", "motion", "gripper", "control", "safety"]
#: what a policy can put behind human approval (`approval.require_for`); `reset_estop` always is
ApprovalAction = Literal["execute", "switch_controllers", "reset_estop", "error_recovery", "set_collision_thresholds"]
#: a `Capabilities` field a backend must have (truthy) for the tool to be registered
Capability = Literal["cameras", "controllers", "graph", "gripper", "collision_thresholds", "error_recovery"]
#: how a planning tool's request is stored and replayed (`Guard.plan`, audit replay)
PlanKind = Literal["joints", "pose", "cartesian"]


@dataclass(frozen=True)
class Hints:
    """The MCP tool annotations (hints to the client; the server enforces nothing by them, but the
    audit log commits read-only calls' records in groups: see `server.app`)."""

    read_only: bool
    destructive: bool
    idempotent: bool
    open_world: bool


#: reads the robot or the world
READS = Hints(read_only=True, destructive=False, idempotent=True, open_world=True)
#: reads the daemon's own state (limits, audit, status)
READS_DAEMON = Hints(read_only=True, destructive=False, idempotent=True, open_world=False)
#: reads the world, a new answer each time (a camera)
OBSERVES = Hints(read_only=True, destructive=False, idempotent=False, open_world=True)
#: computes a plan; never moves anything
PLANS = Hints(read_only=True, destructive=False, idempotent=False, open_world=True)
#: moves or changes the robot
ACTUATES = Hints(read_only=False, destructive=True, idempotent=False, open_world=True)
#: stops the robot
STOPS = Hints(read_only=False, destructive=False, idempotent=True, open_world=True)
#: releases a stop or a fault
RELEASES = Hints(read_only=False, destructive=False, idempotent=False, open_world=True)


@dataclass(frozen=True)
class ToolSpec:
    """One tool. The defaults are those of a plain read of the robot."""

    name: str
    group: ToolGroup
    hints: Hints
    #: the model of its `structuredContent` (`armwarden.results`): the published output schema
    result: type[BaseModel]
    #: registered only when the backend has this capability
    capability: Capability | None = None
    #: an `observer` token may call it (besides the introspect and perception groups)
    observer: bool = False
    #: the rate limiter never throttles it: stopping must always work
    rate_exempt: bool = False
    #: the transport holds the robot the moment it reads a request for it, before it is queued;
    #: it accepts any arguments (a stop is never refused for what it was sent)
    stops_on_read: bool = False
    #: the human approval it can be put behind (`approval.require_for`)
    approval: ApprovalAction | None = None
    #: its result goes into its audit record (off for observations: large, frequent, decide nothing)
    records_result: bool = True
    #: answered even when its audit record cannot be written (saying so): a stop, its status, a release
    answers_unrecorded: bool = False
    #: it moves the robot: a request abandoned by its client stops the motion it started
    moves: bool = False
    #: the `Backend` method through which it moves or changes the robot
    backend_call: str | None = None
    #: its results carry a picture (PNG): a camera image or a plan's preview
    picture: bool = False
    #: a planning tool: the kind of plan it makes
    plan_kind: PlanKind | None = None

    @property
    def observer_may_call(self) -> bool:
        return self.observer or self.group in ("introspect", "perception")
