"""Every tool, in the order of the tool reference, and the sets of names derived from it."""

from __future__ import annotations

from collections.abc import Callable

from armwarden import results as r
from armwarden.tools.spec import (
    ACTUATES,
    OBSERVES,
    PLANS,
    READS,
    READS_DAEMON,
    RELEASES,
    STOPS,
    ToolGroup,
    ToolSpec,
)

#: the public contract: clients and prompts rely on these names
TOOLS: tuple[ToolSpec, ...] = (
    # introspect
    ToolSpec("get_robot_state", "introspect", READS, r.RobotState, records_result=False),
    ToolSpec("get_safety_envelope", "introspect", READS_DAEMON, r.EnvelopeModel, records_result=False),
    ToolSpec("lookup_transform", "introspect", READS, r.TransformResult, records_result=False),
    ToolSpec("list_controllers", "introspect", READS, r.ControllerList, capability="controllers", records_result=False),
    ToolSpec("list_ros_graph", "introspect", READS, r.GraphModel, capability="graph", records_result=False),
    ToolSpec("get_audit_tail", "introspect", READS_DAEMON, r.AuditTail, records_result=False),
    # perception
    ToolSpec("camera_snapshot", "perception", OBSERVES, r.CameraResult, capability="cameras", records_result=False,
             picture=True),
    # motion
    ToolSpec("plan_to_joints", "motion", PLANS, r.PlanSummary, picture=True, plan_kind="joints"),
    ToolSpec("plan_to_pose", "motion", PLANS, r.PlanSummary, picture=True, plan_kind="pose"),
    ToolSpec("plan_cartesian_path", "motion", PLANS, r.PlanSummary, picture=True, plan_kind="cartesian"),
    ToolSpec("execute_plan", "motion", ACTUATES, r.ExecutionReport, approval="execute", moves=True,
             backend_call="execute"),
    ToolSpec("get_plan", "motion", READS_DAEMON, r.PlanSummary, records_result=False),
    ToolSpec("get_motion_status", "motion", READS_DAEMON, r.MotionStatus, records_result=False),
    # gripper
    ToolSpec("gripper_move", "gripper", ACTUATES, r.GripperResultModel, capability="gripper", moves=True,
             backend_call="gripper_move"),
    ToolSpec("gripper_grasp", "gripper", ACTUATES, r.GripperResultModel, capability="gripper", moves=True,
             backend_call="gripper_grasp"),
    ToolSpec("gripper_home", "gripper", ACTUATES, r.GripperResultModel, capability="gripper", moves=True,
             backend_call="gripper_home"),
    # control
    ToolSpec("switch_controllers", "control", ACTUATES, r.ActionResult, capability="controllers",
             approval="switch_controllers", backend_call="switch_controllers"),
    ToolSpec("set_collision_thresholds", "control", ACTUATES, r.ActionResult, capability="collision_thresholds",
             approval="set_collision_thresholds", backend_call="set_collision_thresholds"),
    # safety: always registered (the policy cannot disable the group)
    ToolSpec("stop_motion", "safety", STOPS, r.StopResult, observer=True, rate_exempt=True, stops_on_read=True,
             answers_unrecorded=True),
    ToolSpec("estop", "safety", STOPS, r.EStopResult, observer=True, rate_exempt=True, stops_on_read=True,
             answers_unrecorded=True),
    ToolSpec("reset_estop", "safety", RELEASES, r.ResetResult, approval="reset_estop", answers_unrecorded=True),
    ToolSpec("error_recovery", "safety", RELEASES, r.ActionResult, capability="error_recovery",
             approval="error_recovery", backend_call="error_recovery"),
    ToolSpec("get_safety_status", "safety", READS_DAEMON, r.SafetyStatus, observer=True, rate_exempt=True,
             records_result=False, answers_unrecorded=True),
)

_BY_NAME = {spec.name: spec for spec in TOOLS}


def spec_of(name: str) -> ToolSpec | None:
    """The record of the tool called `name`, or None for a name that is no tool."""
    return _BY_NAME.get(name)


def specs(where: Callable[[ToolSpec], object] | None = None, *, group: ToolGroup | None = None) -> tuple[ToolSpec, ...]:
    """The records (in reference order) of one group and/or for which `where` is true."""
    return tuple(spec for spec in TOOLS if (group is None or spec.group == group) and (where is None or where(spec)))


def names(where: Callable[[ToolSpec], object] | None = None, *, group: ToolGroup | None = None) -> frozenset[str]:
    """The names of the tools `specs(where, group=group)` selects."""
    return frozenset(spec.name for spec in specs(where, group=group))
