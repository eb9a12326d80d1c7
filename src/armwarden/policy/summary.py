"""The human summary `armwarden check-policy` prints, and the JSON schema of the format."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from armwarden.policy.constants import RATE_LIMIT_EXEMPT_TOOLS, TOOL_GROUPS
from armwarden.policy.models import Policy


def _deg(value: float) -> float:
    return math.degrees(value)


def _box_text(lo: Sequence[float], hi: Sequence[float]) -> str:
    return "  ".join(f"{axis} [{a:+.3f}, {b:+.3f}]" for axis, a, b in zip("xyz", lo, hi, strict=True)) + " m"


#: where a human answers a motion's approval, per `approval.channel`
_APPROVAL_CHANNELS = {
    "form": "the MCP client's form",
    "url": "the operator console, linked from the client; never the client's own form",
    "both": "whichever answers first: the MCP client's form or the operator console",
}


def summarize_policy(policy: Policy) -> str:
    """A human-readable, multi-line summary of what the policy allows (`armwarden check-policy`)."""
    robot, ws, motion, force = policy.robot, policy.workspace, policy.motion, policy.force
    lines = [
        f"Policy version {policy.version}",
        f"Robot: {robot.name}  description: {robot.description}  collision geometry: {robot.collision_geometry}",
        f"  base frame: {robot.base_frame}  TCP frame: {robot.tcp_frame}",
        f"  joints ({len(robot.joint_names)}):",
    ]
    width = max(len(name) for name in (*robot.joint_names, "joint"))
    lines.append(
        f"    {'joint':<{width}}  {'position [rad]':<20}  {'position [deg]':<18}  {'vel [rad/s]':>11}"
        f"  {'acc [rad/s²]':>12}  {'home [rad]':>10}"
    )
    for name, home in zip(robot.joint_names, robot.home_joint_positions, strict=True):
        lim = robot.joint_limits[name]
        lines.append(
            f"    {name:<{width}}  [{lim.min:+8.4f}, {lim.max:+8.4f}]  [{_deg(lim.min):+7.1f}, {_deg(lim.max):+7.1f}]"
            f"  {lim.max_velocity:11.3f}  {lim.max_acceleration:12.3f}  {home:+10.4f}"
        )
    lines.append(f"Tool groups: {', '.join(policy.tools.enabled)}  ({len(policy.enabled_tools)} tools)")
    for group in policy.tools.enabled:
        lines.append(f"  {group}: {', '.join(TOOL_GROUPS[group])}")
    lines.append(f"Workspace box ({robot.base_frame}): {_box_text(ws.box.min, ws.box.max)}")
    if ws.keep_out:
        lines.append(f"Keep-out zones ({len(ws.keep_out)}):")
        lines.extend(f"  {zone.name}: {_box_text(zone.min, zone.max)}" for zone in ws.keep_out)
    else:
        lines.append("Keep-out zones: none")
    checked = "every moving link" if ws.check_links is None else ", ".join(ws.check_links) or "none"
    per_link = ", ".join(f"{link} {padding:g} m" for link, padding in ws.padding_by_link_m.items())
    lines.append(
        f"  link padding {ws.link_padding_m:g} m" + (f" ({per_link})" if per_link else "")
        + f"; self-collision {'on' if ws.self_collision else 'OFF'}; checked links: {checked}"
    )
    soft = (
        f"approval above {motion.soft_joint_step_rad:g} rad" if motion.soft_joint_step_rad is not None
        else "no soft threshold"
    )
    lines += [
        f"Motion: velocity scaling ≤ {motion.max_velocity_scaling:g} (default {motion.default_velocity_scaling:g}), "
        f"acceleration scaling ≤ {motion.max_acceleration_scaling:g} (default {motion.default_acceleration_scaling:g})",
        f"  joint travel per plan ≤ {motion.max_joint_step_rad:g} rad ({soft}); "
        f"TCP path ≤ {motion.max_cartesian_step_m:g} m; plan TTL {motion.plan_ttl_s:g} s",
        f"  limit margin {motion.joint_limit_margin_rad:g} rad; start tolerance {motion.start_tolerance_rad:g} rad; "
        f"check resolution {motion.check_resolution_rad:g} rad; sweep resolution {motion.sweep_resolution_m:g} m; "
        f"detour planning budget {motion.planning_time_s:g} s",
        f"Force: ≤ {force.max_contact_force_n:g} N, ≤ {force.max_contact_torque_nm:g} N·m, "
        f"monitored at {force.monitor_rate_hz:g} Hz, wrench older than {force.wrench_timeout_s:g} s aborts; "
        + ("wrench REQUIRED" if force.require_wrench else "wrench NOT required (force may be unenforced)"),
        f"  contact measured by: {force.source}; "
        + ("no joint-torque limits (an arm without a sensor is not monitored)" if force.joint_torques is None else
           "external joint torque ≤ " + ", ".join(f"{v:g}" for v in force.joint_torques.max_external_torque_nm.values())
           + f" N·m, estimated TCP force ≤ {force.estimated_force_limit_n:g} N"
           + f" (observer {force.joint_torques.observer_gain_per_s:g}/s, payload {force.joint_torques.payload_kg:g} kg)"),
    ]
    if policy.gripper is None:
        lines.append("Gripper: none")
    else:
        g = policy.gripper
        lines.append(
            f"Gripper: width {g.min_width_m:g}..{g.max_width_m:g} m, force ≤ {g.max_grasp_force_n:g} N, "
            f"speed ≤ {g.max_speed_mps:g} m/s"
        )
    lines += [
        f"Controllers allowed: {', '.join(policy.controllers.allowlist) or 'none'}",
        f"Cameras allowed: {', '.join(policy.perception.cameras) or 'none'} "
        f"(max image width {policy.perception.max_image_width} px)",
    ]
    rl = policy.rate_limits
    overrides = ", ".join(f"{tool} {rate}/min" for tool, rate in rl.per_tool.items()) or "none"
    lines.append(
        f"Rate limits: {rl.global_per_minute}/min global, {rl.default_per_minute}/min per tool; "
        f"overrides: {overrides}; exempt: {', '.join(RATE_LIMIT_EXEMPT_TOOLS)}"
    )
    ap = policy.approval
    lines.append(
        f"Approval: mode {ap.mode}; required for {', '.join(ap.require_for)}; "
        f"client without elicitation: {ap.on_client_without_elicitation}; "
        f"answered in: {ap.channel} ({_APPROVAL_CHANNELS[ap.channel]})"
        + ("; SELF-APPROVAL ALLOWED: the token that asked may approve its own motion in the console"
           if ap.allow_self_approval else "; self-approval off (another operator approves in the console)")
    )
    lines.append("Dry run: ON (nothing actuates)" if policy.dry_run else "Dry run: off (execution moves the robot)")
    return "\n".join(lines)


def policy_json_schema() -> dict[str, Any]:
    """JSON schema of the policy file (validation mode), e.g. to generate docs/policy.md."""
    return Policy.model_json_schema(mode="validation")
