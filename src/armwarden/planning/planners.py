"""The three planners: to a joint goal, to a TCP pose (IK, then a joint line) and along straight
TCP lines through waypoints (IK at every step).

Planners build trajectories and report what they could not do (`IK_FAILED`, `MALFORMED`) as
violations; whether a trajectory is *allowed* is decided by the envelope, which the Guard runs on
every plan. Velocity/acceleration scaling above the policy's cap is clamped to the cap (the one
clamp the design permits) and the plan says so in its notes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.trajectory import JointTrajectory
from armwarden.planning.timing import TimingError, time_parameterize
from armwarden.robot.ik import IkResult, IkSolver
from armwarden.robot.model import RobotModel
from armwarden.safety.violations import Code, Violation

#: the smallest velocity or acceleration scaling a plan may ask for: below it a motion takes
#: minutes to hours and its trajectory grows without bound (waypoints ∝ 1 / scaling)
MIN_SCALING = 0.01


@dataclass(frozen=True)
class PlannerSettings:
    """Limits and defaults the planners use (from the policy)."""

    max_velocity_rad_s: np.ndarray
    max_acceleration_rad_s2: np.ndarray
    max_velocity_scaling: float
    max_acceleration_scaling: float
    default_velocity_scaling: float
    default_acceleration_scaling: float
    home_rad: np.ndarray
    cartesian_step_m: float = 0.005  # TCP interpolation step of Cartesian paths
    cartesian_step_rad: float = 0.05  # orientation interpolation step of Cartesian paths
    max_ik_jump_rad: float = 0.25  # a larger joint change between consecutive Cartesian steps is a jump

    @classmethod
    def from_policy(cls, policy) -> PlannerSettings:
        robot = policy.robot
        motion = policy.motion
        return cls(
            max_velocity_rad_s=np.array(robot.velocity_limits),
            max_acceleration_rad_s2=np.array(robot.acceleration_limits),
            max_velocity_scaling=motion.max_velocity_scaling,
            max_acceleration_scaling=motion.max_acceleration_scaling,
            default_velocity_scaling=motion.default_velocity_scaling,
            default_acceleration_scaling=motion.default_acceleration_scaling,
            home_rad=np.array(robot.home_joint_positions, dtype=float),
        )


@dataclass(frozen=True)
class PlanOutcome:
    """A trajectory (None when planning failed) with the planner's own findings and notes."""

    trajectory: JointTrajectory | None
    violations: tuple[Violation, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    velocity_scaling: float = 0.0
    acceleration_scaling: float = 0.0


@dataclass(frozen=True)
class PoseTarget:
    """A TCP target in the base frame; `rotation` None keeps the orientation free (position only).

    `free_yaw` (with a `rotation`): any turn of that rotation about the TCP's own z axis (the tool
    axis) will do, so a hand-down grasp keeps its tool pointing down but may choose how the
    fingers lie — the planner picks the turn (`yaw_towards`); without it the rotation is exact."""

    position: np.ndarray
    rotation: np.ndarray | None = None
    free_yaw: bool = False

    def rotation_near(self, current: np.ndarray) -> np.ndarray | None:
        """The rotation to solve IK for from a configuration whose TCP has rotation `current`: the
        given one, or with `free_yaw` its turn about the tool axis closest to `current`."""
        if self.rotation is None or not self.free_yaw:
            return self.rotation
        return yaw_towards(self.rotation, current)


def yaw_about_z(angle: float) -> np.ndarray:
    """The rotation by `angle` [rad] about the z axis."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_towards(rotation: np.ndarray, current: np.ndarray) -> np.ndarray:
    """`rotation` turned about its own z axis to the turn closest to `current` (largest trace of
    the relative rotation, the smallest rotation angle between them): with the tool axis fixed,
    the fingers then lie as close to where they are as the target allows."""
    relative = np.asarray(rotation, dtype=float).T @ np.asarray(current, dtype=float)
    return np.asarray(rotation, dtype=float) @ yaw_about_z(float(np.arctan2(relative[1, 0] - relative[0, 1],
                                                                           relative[0, 0] + relative[1, 1])))


class Planner:
    """Joint, pose and Cartesian planners on one robot model (not thread safe)."""

    def __init__(self, robot: RobotModel, settings: PlannerSettings, ik: IkSolver | None = None) -> None:
        self.robot = robot
        self.settings = settings
        self.ik = ik or IkSolver(robot)

    # ------------------------------------------------------------------ scaling
    def _scaling(self, velocity: float | None, acceleration: float | None) -> tuple[float, float, list[str], list[Violation]]:
        s = self.settings
        notes: list[str] = []
        problems: list[Violation] = []
        chosen = []
        for label, value, default, cap in (
            ("velocity", velocity, s.default_velocity_scaling, s.max_velocity_scaling),
            ("acceleration", acceleration, s.default_acceleration_scaling, s.max_acceleration_scaling),
        ):
            if value is None:
                chosen.append(default)
                continue
            if not np.isfinite(value) or value < MIN_SCALING:
                problems.append(Violation(Code.MALFORMED, f"{label}_scaling must be a finite number in "
                                          f"[{MIN_SCALING:g}, 1], got {value!r}"))
                chosen.append(default)
                continue
            if value > cap:
                notes.append(f"{label}_scaling {value:g} is above the policy cap {cap:g}; clamped to {cap:g}")
                value = cap
            chosen.append(float(value))
        return chosen[0], chosen[1], notes, problems

    def _timed(self, path: np.ndarray, vel: float, acc: float, notes: list[str], stops: tuple[int, ...] = ()) -> PlanOutcome:
        s = self.settings
        try:
            trajectory = time_parameterize(
                self.robot.joint_names, path, s.max_velocity_rad_s * vel, s.max_acceleration_rad_s2 * acc, stops=stops
            )
        except TimingError as exc:
            return PlanOutcome(None, (Violation(Code.ACCELERATION_LIMIT, str(exc)),), tuple(notes), vel, acc)
        return PlanOutcome(trajectory, (), tuple(notes), vel, acc)

    # ------------------------------------------------------------------ planners
    def plan_to_joints(
        self, start: np.ndarray, goal: Sequence[float] | np.ndarray, velocity_scaling: float | None = None,
        acceleration_scaling: float | None = None,
    ) -> PlanOutcome:
        vel, acc, notes, problems = self._scaling(velocity_scaling, acceleration_scaling)
        goal_arr = np.asarray(goal, dtype=float)
        if goal_arr.shape != (self.robot.nq,):
            problems.append(Violation(Code.MALFORMED, f"expected {self.robot.nq} joint positions, got {goal_arr.size}"))
        elif not np.all(np.isfinite(goal_arr)):
            problems.append(Violation(Code.MALFORMED, "joint goal contains NaN or Inf"))
        if problems:
            return PlanOutcome(None, tuple(problems), tuple(notes), vel, acc)
        return self._timed(np.vstack([start, goal_arr]), vel, acc, notes)

    def plan_to_pose(
        self, start: np.ndarray, target: PoseTarget, velocity_scaling: float | None = None, acceleration_scaling: float | None = None
    ) -> PlanOutcome:
        vel, acc, notes, problems = self._scaling(velocity_scaling, acceleration_scaling)
        if problems:
            return PlanOutcome(None, tuple(problems), tuple(notes), vel, acc)
        # a free yaw is solved at the turn nearest the start's first; should IK miss it (a joint
        # limit in the way), at a quarter and half turn from there
        nearest = target.rotation_near(self.robot.tcp_pose(start).rotation)
        seeds = [start, self.settings.home_rad]
        result = self.ik.solve(target.position, nearest, seeds)
        if not result.success and target.free_yaw and nearest is not None:
            for turn in (np.pi / 2, -np.pi / 2, np.pi):
                turned = self.ik.solve(target.position, nearest @ yaw_about_z(turn), seeds)
                if turned.success:
                    result = turned
                    break
        if not result.success:
            return PlanOutcome(None, (Violation(Code.IK_FAILED, result.message, None, self.robot.tcp_frame),), tuple(notes), vel, acc)
        return self._timed(np.vstack([start, result.q]), vel, acc, notes)

    def _cartesian_step(self, position: np.ndarray, rotation: np.ndarray, q: np.ndarray, q_before: np.ndarray) -> IkResult:
        """IK for the next Cartesian step from the previous step's solution; when that lands on
        another branch (a joint jump) or does not converge, retry before the caller reports it:
        from the previous solution extrapolated one step, through a step half as long first,
        then with the joints that rest on a limit taken out of the step (`_solve_at_limits`).
        The first solution within `max_ik_jump_rad` of `q` wins (else the first try's)."""
        limit = self.settings.max_ik_jump_rad
        first = self.ik.solve_from(position, rotation, q)
        if first.success and float(np.max(np.abs(first.q - q))) <= limit:
            return first
        extrapolated = self.ik.solve_from(position, rotation, q + (q - q_before))
        if extrapolated.success and float(np.max(np.abs(extrapolated.q - q))) <= limit:
            return extrapolated
        current = self.robot.tcp_pose(q)
        half_rotation = pin.Quaternion(current.rotation).slerp(0.5, pin.Quaternion(rotation)).toRotationMatrix()
        halfway = self.ik.solve_from((current.position + position) / 2.0, half_rotation, q)
        if halfway.success and float(np.max(np.abs(halfway.q - q))) <= limit:
            retried = self.ik.solve_from(position, rotation, halfway.q)
            if retried.success and float(np.max(np.abs(retried.q - q))) <= limit:
                return retried
        at_limits = self._solve_at_limits(position, rotation, q)
        if at_limits.success and float(np.max(np.abs(at_limits.q - q))) <= limit:
            return at_limits
        return first

    def _solve_at_limits(self, position: np.ndarray, rotation: np.ndarray, q: np.ndarray) -> IkResult:
        """IK from `q` by damped least squares with every joint that rests on a limit and would be
        pushed past it taken out of the step (its Jacobian column zeroed, the step solved again)
        instead of the step being clipped there. Clipping a step that leans on a limit leaves most
        of its error in place, so the solver `IkSolver` uses crawls (a hand held low often has
        joint 6 at its lower limit, and a 5 mm Cartesian step then does not converge in 200
        iterations although the arm can follow the line with its other joints); with the joint
        out of the step the others take the motion at once. The same tolerances and limits."""
        robot, opts = self.robot, self.ik.options
        lower, upper = robot.lower + opts.limit_margin_rad, robot.upper - opts.limit_margin_rad
        damping = opts.damping * np.eye(6)
        q = np.minimum(np.maximum(np.asarray(q, dtype=float), lower), upper)
        pos_err = ori_err = float("inf")
        for iteration in range(1, opts.max_iterations + 1):
            current_position, current_rotation, jac = robot.tcp_pose_and_jacobian(q)
            err = np.concatenate([position - current_position, pin.log3(rotation @ current_rotation.T)])
            pos_err, ori_err = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
            if pos_err < opts.position_tolerance_m and ori_err < opts.orientation_tolerance_rad:
                return IkResult(True, q, pos_err, ori_err, iteration, "converged")
            free = np.ones(len(q), dtype=bool)
            while True:
                masked = jac * free
                dq = masked.T @ np.linalg.solve(masked @ masked.T + damping, err)
                pushed = free & (((q <= lower) & (dq < 0.0)) | ((q >= upper) & (dq > 0.0)))
                if not pushed.any():
                    break
                free &= ~pushed
            largest = float(np.abs(dq).max())
            if largest > opts.max_step_rad:
                dq *= opts.max_step_rad / largest
            q = np.minimum(np.maximum(q + dq, lower), upper)
        return IkResult(False, q, pos_err, ori_err, opts.max_iterations, "did not converge")

    def plan_cartesian_path(
        self,
        start: np.ndarray,
        waypoints: Sequence[PoseTarget],
        velocity_scaling: float | None = None,
        acceleration_scaling: float | None = None,
    ) -> PlanOutcome:
        vel, acc, notes, problems = self._scaling(velocity_scaling, acceleration_scaling)
        if not waypoints:
            problems.append(Violation(Code.MALFORMED, "a Cartesian path needs at least one waypoint"))
        if problems:
            return PlanOutcome(None, tuple(problems), tuple(notes), vel, acc)
        s = self.settings
        current = self.robot.tcp_pose(start)
        position, rotation = current.position, current.rotation
        q = np.asarray(start, dtype=float)
        path = [q]
        stops: list[int] = []
        for index, waypoint in enumerate(waypoints):
            goal_rotation = rotation if waypoint.rotation is None else waypoint.rotation
            distance = float(np.linalg.norm(waypoint.position - position))
            angle = float(np.linalg.norm(pin.log3(rotation.T @ goal_rotation)))
            steps = max(1, int(np.ceil(max(distance / s.cartesian_step_m, angle / s.cartesian_step_rad))))
            q0_rot = pin.Quaternion(rotation)
            q1_rot = pin.Quaternion(goal_rotation)
            for step in range(1, steps + 1):
                alpha = step / steps
                p = position + alpha * (waypoint.position - position)
                r = q0_rot.slerp(alpha, q1_rot).toRotationMatrix()
                result = self._cartesian_step(p, r, q, path[-2] if len(path) > 1 else q)
                if not result.success:
                    return PlanOutcome(
                        None,
                        (Violation(Code.IK_FAILED, f"waypoint {index}: no IK solution on the straight line near "
                                   f"({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}): {result.message}", None, self.robot.tcp_frame),),
                        tuple(notes), vel, acc,
                    )
                jump = float(np.max(np.abs(result.q - q)))
                if jump > s.max_ik_jump_rad:
                    return PlanOutcome(
                        None,
                        (Violation(Code.IK_FAILED, f"waypoint {index}: joint jump of {jump:.3f} rad between "
                                   f"consecutive steps near ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}); the straight "
                                   "line passes a singularity or a limit", None, self.robot.tcp_frame),),
                        tuple(notes), vel, acc,
                    )
                q = result.q
                path.append(q)
            position, rotation = waypoint.position, goal_rotation
            stops.append(len(path) - 1)
        return self._timed(np.vstack(path), vel, acc, notes, tuple(stops))
