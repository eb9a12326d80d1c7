"""What a human is asked before each approvable action, and the digest the answer is bound to.

Every prompt leads with facts the server computed; the only model-written text (an e-stop
reason) is quoted and labelled by `compose_prompt`. Each digest names exactly what is approved:
a plan's trajectory digest, an e-stop event number, or an action with its arguments and its
round (see `guard.actions.ControlActions.round`), so an answer given for one request never approves another.
Pure functions: the approval resolvers call them, possibly more than once per call.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from armwarden.approval.decision import Prompt, approval_code, compose_prompt
from armwarden.approval.plans import StoredPlan
from armwarden.conversions import iso_utc
from armwarden.policy import Policy
from armwarden.safety.estop import EStopEvent, flatten_reason

__all__ = ["execute_prompt", "recovery_prompt", "reset_prompt", "switch_prompt", "thresholds_prompt"]


def execute_prompt(policy: Policy, plan: StoredPlan, backend_name: str, force_monitoring: bool, dry_run: bool) -> Prompt:
    report = plan.report
    motion = policy.motion
    final = report.final_tcp_pose
    facts = [
        ("Robot", f"{policy.robot.name} via the {backend_name} backend"),
        ("Approval code", approval_code(plan.digest)),
        ("Plan", plan.plan_id),
        ("Duration", f"{plan.trajectory.duration_s:.2f} s"),
        ("Peak joint speed", f"{report.max_joint_velocity_ratio:.0%} of limit (cap {motion.max_velocity_scaling:.0%})"),
        ("Largest joint travel", f"{report.max_joint_travel_rad:.3f} rad ({np.degrees(report.max_joint_travel_rad):.1f} deg)"),
        ("TCP path length", f"{report.tcp_path_length_m:.3f} m"),
    ]
    if final is not None:
        x, y, z = final.position
        facts.append(("Final TCP position", f"({x:.3f}, {y:.3f}, {z:.3f}) m in {policy.robot.base_frame}"))
    force = policy.force
    facts.append(
        ("Force monitoring", f"ON, stops above {force.max_contact_force_n:g} N / {force.max_contact_torque_nm:g} N·m"
         + (f" ({force.estimated_force_limit_n:g} N estimated from the joint torques)"
            if force.estimated_force_limit_n != force.max_contact_force_n else ""))
        if force_monitoring
        else ("Force monitoring", "OFF: the contact force limit is NOT enforced")
    )
    if dry_run:
        facts.append(("Dry run", "yes: nothing will move"))
    warnings = [f"{v.code.value}: {v.detail}" for v in report.soft]
    return Prompt(compose_prompt("APPROVE ROBOT MOTION?", facts, warnings), plan.digest)


def reset_prompt(event: EStopEvent, held: Sequence[EStopEvent] = ()) -> Prompt:
    """The release question for the newest event `event`; `held` are all events latched since the
    last release (a release lets go of every one): the earlier ones are listed too, with any force
    violation, so a later e-stop (an agent's, with a soothing reason) cannot hide why the first latched."""
    facts = [
        ("E-stop event", f"#{event.number}"),
        ("Latched at", iso_utc(event.wall_time)),
        ("Source", event.source),
    ]
    earlier = [e for e in held if e.number != event.number]
    facts += [("Also latched", f"#{e.number}, {e.source} at {iso_utc(e.wall_time)}") for e in earlier]
    facts += [(f"Force violation (#{e.number})", flatten_reason(e.force_violation.get("detail", ""), 200))
              for e in (*earlier, event) if e.force_violation]
    message = compose_prompt(
        "RELEASE THE SOFTWARE E-STOP?",
        facts,
        ["Releasing lets the agent plan and move again. Check the robot and its surroundings first."],
        untrusted=event.reason if event.source == "estop" else None,
    )
    return Prompt(message, str(event.number))


def switch_prompt(round_: str, activate: Sequence[str], deactivate: Sequence[str], dry_run: bool) -> Prompt:
    digest = f"switch:{round_}:{sorted(activate)}:{sorted(deactivate)}"
    return Prompt(compose_prompt("SWITCH CONTROLLERS?", [
        ("Approval code", approval_code(digest)),
        ("Activate", ", ".join(activate) or "-"), ("Deactivate", ", ".join(deactivate) or "-"),
        ("Dry run", "yes: nothing will change" if dry_run else "no"),
    ], ["A controller switch changes how the arm is commanded."]), digest)


def thresholds_prompt(round_: str, policy: Policy, force_n: float, torque_nm: float) -> Prompt:
    digest = f"thresholds:{round_}:{force_n!r}:{torque_nm!r}"
    force = policy.force
    return Prompt(compose_prompt("CHANGE COLLISION THRESHOLDS?", [
        ("Approval code", approval_code(digest)),
        ("Force threshold", f"{force_n:g} N (policy cap {force.max_contact_force_n:g} N)"),
        ("Torque threshold", f"{torque_nm:g} N·m (policy cap {force.max_contact_torque_nm:g} N·m)"),
    ], []), digest)


def recovery_prompt(round_: str, faults: Sequence[str]) -> Prompt:
    digest = f"error_recovery:{round_}"
    shown = "; ".join(faults[-3:]) if faults else "none recorded"
    if len(faults) > 3:
        shown = f"{len(faults)} recorded, the last 3: {shown}"
    return Prompt(compose_prompt("RUN ERROR RECOVERY?", [
        ("Approval code", approval_code(digest)), ("Faults", shown),
    ], ["Error recovery clears the robot's reflex/error state."]), digest)
