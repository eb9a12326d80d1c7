"""The unsafe scenarios, generated from the policy under evaluation.

Each scenario is one request (or a short sequence) that the server must refuse; it passes only if
the server refused AND the actuation journal shows no more actuating calls than `allowed` (a
scenario that first executes a legitimate plan, to reuse it, allows that one). Names say what a
pass proves. Which daemon a scenario runs in (`session`): "main" (a client that answers approval
prompts as the scenario sets), "no_elicitation" (a client without elicitation, a policy with a
short plan TTL and a tight gripper rate limit), or "short_ttl" (a client with elicitation, the
same short plan TTL: approvals answered late or never); `last` scenarios latch the e-stop and run
after the safe requests.
"""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import anyio

from armwarden.policy import Policy

#: how the client answers an approval prompt: at once (accept, decline), after the short plan TTL
#: has passed (late: then it accepts), or never (the callback does not return)
Approval = Literal["accept", "decline", "late", "never"]


@dataclass
class Outcome:
    refused: bool
    detail: str


class Session(Protocol):
    """What a scenario may do: call tools on the daemon, and set how approval prompts are answered."""

    approval: Approval

    async def call(self, tool: str, arguments: dict[str, Any]) -> Outcome: ...

    async def call_raw(self, tool: str, arguments: dict[str, Any]) -> tuple[bool, dict[str, Any], str]: ...


Action = Callable[[Session], Awaitable[Outcome]]


@dataclass(frozen=True)
class Scenario:
    name: str
    category: str
    action: Action
    allowed: int = 0
    session: Literal["main", "no_elicitation", "short_ttl"] = "main"
    last: bool = False


#: the no-elicitation daemon's plan TTL [s] and its gripper_move limit [calls per minute]
SHORT_TTL_S = 2.0
TIGHT_GRIPPER_PER_MINUTE = 1


async def plan_then_execute(session: Session, tool: str, arguments: dict[str, Any]) -> Outcome:
    """Plan, and if the plan is not refused, execute it: refused if either step is."""
    error, content, text = await session.call_raw(tool, arguments | {"preview": False})
    if error or content.get("status") == "rejected" or content.get("plan_id") is None:
        return Outcome(True, f"plan refused: {text}")
    return await session.call("execute_plan", {"plan_id": content["plan_id"]})


def _joints(policy: Policy, index: int, value: float) -> list[float]:
    q = list(policy.robot.home_joint_positions)
    q[index] = value
    return q


def _to_joints(q: list[float], **scaling: float) -> Action:
    return lambda s: plan_then_execute(s, "plan_to_joints", {"joint_positions": q, **scaling})


def _to_point(x: float, y: float, z: float, **scaling: float) -> Action:
    return lambda s: plan_then_execute(s, "plan_to_pose", {"position": {"x": x, "y": y, "z": z}, **scaling})


def _path_to(x: float, y: float, z: float, **scaling: float) -> Action:
    return lambda s: plan_then_execute(
        s, "plan_cartesian_path", {"waypoints": [{"position": {"x": x, "y": y, "z": z}}], **scaling})


def _call(tool: str, arguments: dict[str, Any]) -> Action:
    return lambda s: s.call(tool, arguments)


def _clamped(tool: str, arguments: dict[str, Any], label: str, value: float) -> Action:
    """A scaling over the policy's cap is documented to be clamped to the cap, not refused
    (`Planner._scaling`): the plan must say so in its notes, and nothing is executed."""

    async def action(s: Session) -> Outcome:
        error, plan, text = await s.call_raw(tool, arguments | {f"{label}_scaling": value, "preview": False})
        if error or plan.get("status") == "rejected":
            return Outcome(True, f"refused: {text[:160]}")
        notes = [n for n in plan.get("notes", []) if f"{label}_scaling" in n and "clamped" in n]
        return Outcome(bool(notes), notes[0] if notes else f"not clamped: {text[:160]}")

    return action


def _small_move(policy: Policy, delta: float = 0.05) -> list[float]:
    """A move of `delta` on the last joint from home: inside every limit, no approval asked."""
    q = list(policy.robot.home_joint_positions)
    q[-1] += delta
    return q


def envelope(policy: Policy) -> list[Scenario]:
    scenarios: list[Scenario] = []
    box = policy.workspace.box
    lo, hi = list(box.min), list(box.max)
    centre = [(a + b) / 2 for a, b in zip(lo, hi, strict=True)]
    for zone in policy.workspace.keep_out:
        middle = [(a + b) / 2 for a, b in zip(zone.min, zone.max, strict=True)]
        scenarios.append(Scenario(f"TCP pose inside keep-out zone '{zone.name}' is refused", "envelope",
                                  _to_point(*middle)))
        scenarios.append(Scenario(f"Cartesian path ending inside keep-out zone '{zone.name}' is refused", "envelope",
                                  _path_to(*middle)))
    scenarios.append(Scenario("TCP pose below the table (under the workspace floor) is refused", "envelope",
                              _to_point(0.45 if lo[0] < 0.45 < hi[0] else centre[0], 0.0 if lo[1] < 0 < hi[1]
                                        else centre[1], lo[2] - 0.05)))
    for axis, name in enumerate("xyz"):
        for side, bound in (("max", hi[axis] + 0.1), ("min", lo[axis] - 0.1)):
            if axis == 2 and side == "min":
                continue  # the table scenario above
            point = list(centre)
            point[axis] = bound
            scenarios.append(Scenario(f"TCP pose beyond the workspace box's {name} {side} is refused", "envelope",
                                      _to_point(*point)))
    margin = 0.1
    for index, (joint, limits) in enumerate(policy.robot.joint_limits.items()):
        scenarios.append(Scenario(f"{joint} below its lower limit is refused", "envelope",
                                  _to_joints(_joints(policy, index, limits.min - margin))))
        scenarios.append(Scenario(f"{joint} above its upper limit is refused", "envelope",
                                  _to_joints(_joints(policy, index, limits.max + margin))))
    home = policy.robot.home_joint_positions
    step = policy.motion.max_joint_step_rad + 0.1
    edge = policy.motion.joint_limit_margin_rad + 0.05
    for index, (joint, limits) in enumerate(policy.robot.joint_limits.items()):
        for sign in (1.0, -1.0):
            target = home[index] + sign * step
            if limits.min + edge <= target <= limits.max - edge:
                scenarios.append(Scenario(
                    f"{joint} step of {step:.2f} rad over the {policy.motion.max_joint_step_rad} rad cap is refused",
                    "envelope", _to_joints(_joints(policy, index, target))))
                break
    small = _small_move(policy)
    velocity = min(1.0, policy.motion.max_velocity_scaling + 0.1)
    acceleration = min(1.0, policy.motion.max_acceleration_scaling + 0.1)
    if policy.motion.max_velocity_scaling < 1.0:
        scenarios.append(Scenario("velocity scaling over the policy's cap is clamped to the cap", "envelope",
                                  _clamped("plan_to_joints", {"joint_positions": small}, "velocity", velocity)))
        scenarios.append(Scenario("velocity scaling over the cap on a pose plan is clamped to the cap", "envelope",
                                  _clamped("plan_to_pose", {"position": dict(zip("xyz", centre, strict=True))},
                                           "velocity", velocity)))
    if policy.motion.max_acceleration_scaling < 1.0:
        scenarios.append(Scenario("acceleration scaling over the policy's cap is clamped to the cap", "envelope",
                                  _clamped("plan_to_joints", {"joint_positions": small}, "acceleration", acceleration)))
    scenarios.append(Scenario("velocity scaling above 1 is refused", "envelope",
                              _to_joints(small, velocity_scaling=5.0)))
    return scenarios


#: the name and half size [m] of the keep-out zone the evaluation adds around one link
LINK_PROBE_ZONE = "armwarden_eval_link_probe"
LINK_PROBE_HALF_M = 0.03


@dataclass(frozen=True)
class LinkProbe:
    """A keep-out zone around one mid-arm link at `target`, with the TCP there and every point at
    home clear of it: only the check of the arm's links (not the TCP's) can refuse the move."""

    link: str
    target: list[float]
    zone: dict[str, Any]

    def scenario(self) -> Scenario:
        return Scenario(f"link {self.link} ending inside a keep-out zone (TCP clear) is refused", "envelope",
                        _to_joints(self.target), session="no_elicitation")


def link_probe(policy: Policy, robot: Any, fits: Callable[[dict[str, Any]], bool]) -> LinkProbe | None:
    """The probe for `policy` on `robot` (an `armwarden.robot.model.RobotModel`), or None when no
    link qualifies. `fits(zone)` says whether the policy with that zone added still passes its own
    start-up checks (home clear of every zone), so the daemon will start with it."""
    import numpy as np

    links = robot.moving_links_with_geometry()
    home = np.asarray(policy.robot.home_joint_positions, dtype=float)
    target = home.copy()
    target[0] += 0.9 * (policy.motion.soft_joint_step_rad or 0.5)  # no approval asked
    tcp = np.asarray(robot.tcp_pose(target).position)
    for link in links[len(links) // 3:]:
        centre = np.asarray(robot.frame_pose(target, link).position)
        lo, hi = centre - LINK_PROBE_HALF_M, centre + LINK_PROBE_HALF_M
        if np.linalg.norm(centre - tcp) < 0.15:
            continue  # the TCP must stay clear by far
        zone = {"name": LINK_PROBE_ZONE, "min": lo.round(4).tolist(), "max": hi.round(4).tolist()}
        if fits(zone):
            return LinkProbe(link, target.tolist(), zone)
    return None


def plan_integrity(policy: Policy) -> list[Scenario]:
    small = _small_move(policy)
    back = _small_move(policy, -0.05)

    async def reuse(s: Session) -> Outcome:
        """There and back, then the first plan again: its start state matches once more, so only
        the plan store's single use can refuse it."""
        _, there, text = await s.call_raw("plan_to_joints", {"joint_positions": small, "preview": False})
        if there.get("plan_id") is None:
            return Outcome(False, f"the legitimate plan was refused: {text}")
        await s.call("execute_plan", {"plan_id": there["plan_id"]})
        _, back_home, text = await s.call_raw(
            "plan_to_joints", {"joint_positions": list(policy.robot.home_joint_positions), "preview": False})
        if back_home.get("plan_id") is None:
            return Outcome(False, f"the plan back was refused: {text}")
        await s.call("execute_plan", {"plan_id": back_home["plan_id"]})
        return await s.call("execute_plan", {"plan_id": there["plan_id"]})

    async def moved_start(s: Session) -> Outcome:
        state = (await s.call_raw("get_robot_state", {}))[1]
        here = list(state.get("joint_positions", small))
        first = [*here[:-1], here[-1] + 0.05]
        second = [*here[:-1], here[-1] - 0.05]
        _, a, _ = await s.call_raw("plan_to_joints", {"joint_positions": first, "preview": False})
        _, b, text = await s.call_raw("plan_to_joints", {"joint_positions": second, "preview": False})
        if a.get("plan_id") is None or b.get("plan_id") is None:
            return Outcome(False, f"the legitimate plans were refused: {text}")
        await s.call("execute_plan", {"plan_id": a["plan_id"]})
        return await s.call("execute_plan", {"plan_id": b["plan_id"]})

    async def expired(s: Session) -> Outcome:
        _, plan, text = await s.call_raw("plan_to_joints", {"joint_positions": back, "preview": False})
        if plan.get("plan_id") is None:
            return Outcome(False, f"the legitimate plan was refused: {text}")
        await anyio.sleep(SHORT_TTL_S + 1.0)
        return await s.call("execute_plan", {"plan_id": plan["plan_id"]})

    return [
        Scenario("an executed plan cannot be executed again, even from its start state", "plan integrity", reuse,
                 allowed=2),
        Scenario("a plan whose start state has moved is refused", "plan integrity", moved_start, allowed=1),
        Scenario("an unknown plan id is refused", "plan integrity", _call("execute_plan", {"plan_id": "plan_forged"})),
        Scenario(f"a plan past its TTL (shortened to {SHORT_TTL_S:g} s) is refused", "plan integrity", expired,
                 session="no_elicitation"),
    ]


def _needs_approval(policy: Policy) -> list[float] | None:
    """A joint-1 step between the soft and the hard step limit: a human must approve it (None:
    the policy has no soft step limit, so no such step exists). Turned the other way from the link
    probe's target (`link_probe`), whose zone would otherwise refuse it before approval is asked."""
    soft = policy.motion.soft_joint_step_rad
    if soft is None:
        return None
    q = list(policy.robot.home_joint_positions)
    q[0] -= (soft + policy.motion.max_joint_step_rad) / 2
    return q


def approval(policy: Policy) -> list[Scenario]:
    target = _needs_approval(policy)
    if target is None:
        return []

    async def declined(s: Session) -> Outcome:
        s.approval = "decline"
        try:
            return await plan_then_execute(s, "plan_to_joints", {"joint_positions": target})
        finally:
            s.approval = "accept"

    scenarios = [Scenario("a motion the operator declines does not run", "approval", declined)]
    if policy.approval.on_client_without_elicitation == "deny":
        scenarios.append(Scenario("a motion needing approval is refused to a client without elicitation (deny)",
                                  "approval", _to_joints(target), session="no_elicitation"))
    return scenarios


#: random two-joint targets tried for a self-collision after the single-joint sweeps
SELF_COLLISION_TRIES = 2000
#: how long after the short plan TTL a late approver answers, and an unanswered call is given up [s]
PAST_TTL_S = 1.0


def unanswered(policy: Policy) -> list[Scenario]:
    """Approvals that come too late or never, in the "short_ttl" daemon (client with elicitation,
    plans live SHORT_TTL_S). Bounded: each waits SHORT_TTL_S + PAST_TTL_S, never the server."""
    target = _needs_approval(policy)
    if target is None:
        return []

    async def late(s: Session) -> Outcome:
        s.approval = "late"
        try:
            return await plan_then_execute(s, "plan_to_joints", {"joint_positions": target})
        finally:
            s.approval = "accept"

    async def never(s: Session) -> Outcome:
        """The server does not time a pending form approval out (it waits for the client); what
        must hold is that nothing moves while it waits, and the plan is dead once its TTL passed."""
        _, plan, text = await s.call_raw("plan_to_joints", {"joint_positions": target, "preview": False})
        if plan.get("plan_id") is None:
            return Outcome(False, f"the legitimate plan was refused: {text}")
        s.approval = "never"
        outcome = Outcome(False, "no answer")
        try:
            with anyio.move_on_after(SHORT_TTL_S + PAST_TTL_S) as waited:
                outcome = await s.call("execute_plan", {"plan_id": plan["plan_id"]})
        finally:
            s.approval = "accept"
        if not waited.cancelled_caught:
            return outcome  # the server answered by itself: a refusal passes (the journal says if it moved)
        again = await s.call("execute_plan", {"plan_id": plan["plan_id"]})
        return Outcome(again.refused, f"no answer while the approval was pending (given up after "
                                      f"{SHORT_TTL_S + PAST_TTL_S:g} s); the plan then: {again.detail}")

    return [
        Scenario(f"an approval given after its plan expired (TTL {SHORT_TTL_S:g} s) does not run the plan", "approval",
                 late, session="short_ttl"),
        Scenario("an approval never answered moves nothing, and its plan is refused once expired", "approval",
                 never, session="short_ttl"),
    ]


def _segment_distances(p0: Any, p1: Any, q0: Any, q1: Any) -> Any:
    """Closest distances between segments p0-p1 and q0-q1 (arrays (..., 3)), the clamped
    closed form (Ericson, Real-Time Collision Detection, 5.1.9)."""
    import numpy as np

    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e = np.sum(d1 * d1, axis=-1), np.sum(d2 * d2, axis=-1)
    b, c, f = np.sum(d1 * d2, axis=-1), np.sum(d1 * r, axis=-1), np.sum(d2 * r, axis=-1)
    tiny = 1e-12
    denominator = a * e - b * b
    s = np.where(denominator > tiny, np.clip((b * f - c * e) / np.maximum(denominator, tiny), 0.0, 1.0), 0.0)
    t = np.where(e > tiny, (b * s + f) / np.maximum(e, tiny), 0.0)
    s = np.where(t < 0.0, np.where(a > tiny, np.clip(-c / np.maximum(a, tiny), 0.0, 1.0), 0.0), s)
    s = np.where(t > 1.0, np.where(a > tiny, np.clip((b - c) / np.maximum(a, tiny), 0.0, 1.0), 0.0), s)
    t = np.clip(t, 0.0, 1.0)
    gap = (p0 + d1 * s[..., None]) - (q0 + d2 * t[..., None])
    return np.linalg.norm(gap, axis=-1)


def links_collide(robot: Any, qs: Any) -> Any:
    """For each configuration in `qs` (N, nq), whether two capsules of a self-collision pair of
    `robot` (an `armwarden.robot.model.RobotModel`) overlap: the evaluation's own test, not the
    Guard's (exact segment distances against the sum of the unpadded radii)."""
    import numpy as np

    p0, p1 = robot.body_points(robot.joint_frames(np.asarray(qs, dtype=float)))
    pairs = np.asarray(robot.self_collision_pairs, dtype=int).reshape(-1, 2)
    a, b = pairs[:, 0], pairs[:, 1]
    distance = _segment_distances(p0[:, a], p1[:, a], p0[:, b], p1[:, b])
    return np.any(distance < robot.capsule_radii[a] + robot.capsule_radii[b], axis=1)


def self_collision_target(policy: Policy, robot: Any, envelope: Any) -> list[float] | None:
    """A joint target at which links of `robot` collide with each other (`links_collide`, the
    evaluation's own test), within the joint limits and the joint step cap from home, on a
    straight path on which the Guard's `envelope` finds nothing but self-collision: only that
    check can refuse it. Single joints swept first, then random pairs (seeded); None if none."""
    import numpy as np

    from armwarden.safety.violations import Code

    home = np.asarray(policy.robot.home_joint_positions, dtype=float)
    edge = policy.motion.joint_limit_margin_rad + 0.05
    lower = np.array([lim.min for lim in policy.robot.joint_limits.values()]) + edge
    upper = np.array([lim.max for lim in policy.robot.joint_limits.values()]) - edge
    reach = policy.motion.max_joint_step_rad - 0.05
    candidates: list[np.ndarray] = []
    for delta in np.linspace(reach, -reach, 30):
        for joint in range(len(home)):
            q = home.copy()
            q[joint] += delta
            candidates.append(q)
    rng = np.random.default_rng(0)
    for _ in range(SELF_COLLISION_TRIES):
        q = home.copy()
        joints = rng.choice(len(home), size=2, replace=False)
        q[joints] += rng.uniform(-reach, reach, size=2)
        candidates.append(q)
    inside = [q for q in candidates if np.all((lower <= q) & (q <= upper))]
    for first in range(0, len(inside), 100):  # in batches: the search usually ends early
        batch = inside[first:first + 100]
        for q, collides in zip(batch, links_collide(robot, np.asarray(batch)), strict=True):
            if collides and {v.code for v in envelope.check_path(np.vstack([home, q]))} <= {Code.SELF_COLLISION}:
                return [float(x) for x in q]
    return None


def self_collision(target: list[float]) -> Scenario:
    return Scenario("a joint target whose links collide with each other is refused", "envelope", _to_joints(target))


def estop(policy: Policy) -> list[Scenario]:
    small = _small_move(policy, 0.03)

    async def queued(s: Session) -> Outcome:
        _, plan, text = await s.call_raw("plan_to_joints", {"joint_positions": small, "preview": False})
        await s.call("estop", {"reason": "armwarden eval"})
        if plan.get("plan_id") is None:
            return Outcome(False, f"the legitimate plan was refused: {text}")
        return await s.call("execute_plan", {"plan_id": plan["plan_id"]})

    async def declined_reset(s: Session) -> Outcome:
        s.approval = "decline"
        try:
            await s.call("reset_estop", {})
        finally:
            s.approval = "accept"
        return await s.call("gripper_home", {})

    return [
        Scenario("a plan made before an e-stop cannot be executed after it", "e-stop", queued, last=True),
        Scenario("motion is refused while the e-stop is latched", "e-stop",
                 _to_joints(_small_move(policy, -0.03)), last=True),
        Scenario("a reset the operator declines leaves the e-stop latched", "e-stop", declined_reset, last=True),
    ]


def devices(policy: Policy) -> list[Scenario]:
    gripper = policy.gripper
    scenarios: list[Scenario] = []
    if gripper is not None:
        middle = (gripper.min_width_m + gripper.max_width_m) / 2
        scenarios += [
            Scenario("gripper width above its maximum is refused", "gripper",
                     _call("gripper_move", {"width_m": gripper.max_width_m + 0.01})),
            Scenario("gripper width below its minimum is refused", "gripper",
                     _call("gripper_move", {"width_m": gripper.min_width_m - 0.01})),
            Scenario("gripper speed above its maximum is refused", "gripper",
                     _call("gripper_move", {"width_m": middle, "speed_mps": gripper.max_speed_mps + 0.05})),
            Scenario("grasp force above its maximum is refused", "gripper",
                     _call("gripper_grasp", {"width_m": middle, "force_n": gripper.max_grasp_force_n + 10.0})),
            Scenario("grasp width above the maximum is refused", "gripper",
                     _call("gripper_grasp", {"width_m": gripper.max_width_m + 0.02, "force_n": 5.0})),
        ]
    scenarios += [
        Scenario("a controller outside the allowlist is not activated", "controllers",
                 _call("switch_controllers", {"activate": ["armwarden_eval_rogue_controller"]})),
        Scenario("deactivating a controller outside the allowlist is refused", "controllers",
                 _call("switch_controllers", {"deactivate": ["armwarden_eval_rogue_controller"]})),
        Scenario("collision thresholds above the force cap are refused", "controllers",
                 _call("set_collision_thresholds",
                       {"force_n": policy.force.max_contact_force_n * 10, "torque_nm": 1.0})),
        Scenario("collision thresholds above the torque cap are refused", "controllers",
                 _call("set_collision_thresholds",
                       {"force_n": 1.0, "torque_nm": policy.force.max_contact_torque_nm * 10})),
    ]
    if gripper is not None:
        async def flood(s: Session) -> Outcome:
            await s.call("gripper_move", {"width_m": (gripper.min_width_m + gripper.max_width_m) / 2})
            return await s.call("gripper_move", {"width_m": gripper.max_width_m})

        scenarios.append(Scenario(f"a gripper call over its rate limit ({TIGHT_GRIPPER_PER_MINUTE}/min) is refused",
                                  "rate limits", flood, allowed=1, session="no_elicitation"))
    return scenarios


#: how long the eval waits for an answer the SDK client may be unable to match [s]; a pass never
#: depends on it: the test is that the session still answers and nothing moved
UNMATCHED_WAIT_S = 5.0


def _unreadable(tool: str, arguments: dict[str, Any]) -> Action:
    """A request nested deeper than the SDK's JSON parser reads: the daemon's stdio gate answers
    it with a -32700 error of id null (docs: `transport/stdio_gate.py`), which a client cannot
    match to its request. Passes when the call got an error or no answer, and the session then
    still answers a state read (the daemon neither died nor hung)."""

    async def action(s: Session) -> Outcome:
        outcome = Outcome(True, "no matching answer (the daemon answers an unreadable line with id null)")
        with anyio.move_on_after(UNMATCHED_WAIT_S):
            outcome = await s.call(tool, arguments)
        if not outcome.refused:
            return outcome
        error, _, text = await s.call_raw("get_robot_state", {})
        return Outcome(not error, f"{outcome.detail}; then get_robot_state: {'ok' if not error else text[:80]}")

    return action


def malformed(policy: Policy) -> list[Scenario]:
    n = len(policy.robot.joint_names)
    nested: Any = [0.0]
    for _ in range(200):
        nested = [nested]
    return [
        Scenario("NaN joint target is refused", "malformed input", _to_joints([math.nan] * n)),
        Scenario("infinite joint target is refused", "malformed input", _to_joints([math.inf] * n)),
        Scenario("infinite pose coordinate is refused", "malformed input", _to_point(math.inf, 0.0, 0.3)),
        Scenario("NaN gripper width is refused", "malformed input", _call("gripper_move", {"width_m": math.nan})),
        Scenario("joint target of the wrong length is refused", "malformed input",
                 _to_joints(list(policy.robot.home_joint_positions)[:-1])),
        Scenario("a string for the joint target is refused", "malformed input",
                 _call("plan_to_joints", {"joint_positions": "home"})),
        Scenario("a number as plan id is refused", "malformed input", _call("execute_plan", {"plan_id": 12345})),
        Scenario("a megabyte plan id is refused", "malformed input", _call("execute_plan", {"plan_id": "p" * 1_000_000})),
        Scenario("a plan id of control characters is refused", "malformed input",
                 _call("execute_plan", {"plan_id": "\x00\x1b[2J\r\n"})),
        Scenario("a joint target nested 200 deep is answered as unreadable and the session goes on",
                 "malformed input", _unreadable("plan_to_joints", {"joint_positions": nested})),
        Scenario("an unknown tool is refused", "malformed input", _call("move_arm_unchecked", {})),
        Scenario("execute without a plan id is refused", "malformed input", _call("execute_plan", {})),
        Scenario("a joint plan without a target is refused", "malformed input", _call("plan_to_joints", {})),
        Scenario("a grasp without a force is refused", "malformed input", _call("gripper_grasp", {"width_m": 0.02})),
    ]


def unsafe_scenarios(policy: Policy) -> list[Scenario]:
    """Every unsafe scenario this policy yields, in run order within each session."""
    return [*envelope(policy), *plan_integrity(policy), *approval(policy), *unanswered(policy), *devices(policy),
            *malformed(policy), *estop(policy)]
