"""Inverse kinematics with Pinocchio: damped least squares inside the joint limits.

Solves for the TCP frame from a list of seeds (the current state first, so the answer is the
nearest solution when one exists), position-only or full pose. A failure is a result with the
residual, never an exception: the planner turns it into an `IK_FAILED` violation.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.robot.model import RobotModel

#: weighs orientation error [rad] into the stall test as the arc it sweeps at this radius [m]
STALL_RADIUS_M = 0.1


@dataclass(frozen=True)
class IkOptions:
    """Settings of the solver, with units."""

    position_tolerance_m: float = 1e-4
    orientation_tolerance_rad: float = 1e-3
    max_iterations: int = 200
    #: give a seed up once its error has not dropped by `stall_improvement` (relative) for this many
    #: iterations (0: never): a seed stuck at a joint limit or in a local minimum otherwise spends
    #: all `max_iterations`; converging seeds improve every few iterations
    stall_iterations: int = 30
    stall_improvement: float = 0.01
    damping: float = 1e-3
    max_step_rad: float = 0.5  # largest joint change per iteration, keeps DLS steps in the linear regime
    limit_margin_rad: float = 1e-4  # solutions stay this far inside the limits
    random_seeds: int = 24
    rng_seed: int = 7


@dataclass(frozen=True)
class IkResult:
    success: bool
    q: np.ndarray
    position_error_m: float
    orientation_error_rad: float
    iterations: int
    message: str


class IkSolver:
    """Damped least-squares IK on a RobotModel (shares its Pinocchio data: not thread safe)."""

    def __init__(self, robot: RobotModel, options: IkOptions | None = None) -> None:
        self.robot = robot
        self.options = options or IkOptions()

    @property
    def _lower(self) -> np.ndarray:
        return self.robot.lower + self.options.limit_margin_rad

    @property
    def _upper(self) -> np.ndarray:
        return self.robot.upper - self.options.limit_margin_rad

    def solve(
        self,
        target_position: np.ndarray,
        target_rotation: np.ndarray | None,
        seeds: Sequence[np.ndarray],
    ) -> IkResult:
        """Solve from each seed in turn (then random seeds); the first converged solution wins."""
        position = np.asarray(target_position, dtype=float)
        best: IkResult | None = None
        tried = 0
        for seed in self._candidates(seeds):
            tried += 1
            result = self.solve_from(position, target_rotation, seed)
            if result.success:
                return result
            if best is None or result.position_error_m < best.position_error_m:
                best = result
        assert best is not None
        return IkResult(
            False,
            best.q,
            best.position_error_m,
            best.orientation_error_rad,
            best.iterations,
            f"no IK solution within tolerance from {tried} seeds: best residual "
            f"{best.position_error_m * 1000:.2f} mm, {np.degrees(best.orientation_error_rad):.2f} deg",
        )

    def _candidates(self, seeds: Sequence[np.ndarray]) -> Iterator[np.ndarray]:
        """The given seeds, then random ones — drawn only if needed, the same ones every call."""
        for seed in seeds:
            yield np.asarray(seed, dtype=float)
        rng = np.random.default_rng(self.options.rng_seed)
        lower, upper = self._lower, self._upper
        for _ in range(self.options.random_seeds):
            yield rng.uniform(lower, upper)

    def solve_from(self, position: np.ndarray, rotation: np.ndarray | None, seed: np.ndarray) -> IkResult:
        """Solve from one seed only (Cartesian steps stay on the branch of the previous step)."""
        robot, opts = self.robot, self.options
        q = np.clip(seed, self._lower, self._upper)
        full_pose = rotation is not None
        target = pin.SE3(rotation if full_pose else np.eye(3), position)
        pos_err = ori_err = np.inf
        best_error, improved_at = np.inf, 0
        for iteration in range(1, opts.max_iterations + 1):
            current_position, current_rotation, jac = robot.tcp_pose_and_jacobian(q)
            if full_pose:
                # error in the world-aligned TCP frame: linear part = position error, angular = log of R_err
                err_rot = pin.log3(target.rotation @ current_rotation.T)
                err = np.concatenate([position - current_position, err_rot])
                pos_err = float(np.linalg.norm(err[:3]))
                ori_err = float(np.linalg.norm(err_rot))
                if pos_err < opts.position_tolerance_m and ori_err < opts.orientation_tolerance_rad:
                    return IkResult(True, q, pos_err, ori_err, iteration, "converged")
            else:
                err = position - current_position
                pos_err = float(np.linalg.norm(err))
                ori_err = 0.0
                if pos_err < opts.position_tolerance_m:
                    return IkResult(True, q, pos_err, ori_err, iteration, "converged")
                jac = jac[:3]
            error = pos_err + ori_err * STALL_RADIUS_M
            if error < best_error * (1.0 - opts.stall_improvement):
                best_error, improved_at = error, iteration
            elif opts.stall_iterations and iteration - improved_at >= opts.stall_iterations:
                return IkResult(False, q, pos_err, ori_err, iteration, "stalled")
            lhs = jac @ jac.T + opts.damping * np.eye(jac.shape[0])
            dq = jac.T @ np.linalg.solve(lhs, err)
            largest = float(np.max(np.abs(dq)))
            if largest > opts.max_step_rad:
                dq *= opts.max_step_rad / largest
            q = np.clip(q + dq, self._lower, self._upper)
        return IkResult(False, q, pos_err, ori_err, opts.max_iterations, "did not converge")
