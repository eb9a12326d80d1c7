"""Inverse kinematics with Pinocchio: damped least squares inside the joint limits.

Solves for the TCP frame from a list of seeds (the current state first, so the answer is the
nearest solution when one exists), position-only or full pose. A failure is a result with the
residual, never an exception: the planner turns it into an `IK_FAILED` violation.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import eigenpy  # pyright: ignore[reportMissingImports] - installed with pin (its linear algebra), behind the same .pth hook
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

    def __post_init__(self) -> None:
        # J Jᵀ + λI is positive definite only for λ > 0, and the Cholesky step (eigenpy's LLT)
        # does not report a matrix that is not: it returns a wrong step in silence
        if not (math.isfinite(self.damping) and self.damping > 0.0):
            raise ValueError(f"IK damping must be a finite number > 0, got {self.damping!r}")


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
        # fixed per solver: the inner loop runs ~30 times per solve and goal selection solves
        # dozens of times per plan, so nothing here is recomputed per iteration
        self._lower = robot.lower + self.options.limit_margin_rad
        self._upper = robot.upper - self.options.limit_margin_rad
        self._damping = {size: self.options.damping * np.eye(size) for size in (3, 6)}

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
        """Solve from one seed only (Cartesian steps stay on the branch of the previous step).

        Each iteration is one damped least-squares step, dq = Jᵀ (J Jᵀ + λI)⁻¹ e, solved by
        Cholesky (J Jᵀ + λI is symmetric positive definite) with eigenpy, Pinocchio's own linear
        algebra: NumPy's general solver costs three times as much per call on these 6×6 systems."""
        robot, opts = self.robot, self.options
        lower, upper = self._lower, self._upper
        q = np.minimum(np.maximum(np.asarray(seed, dtype=float), lower), upper)
        full_pose = rotation is not None
        target_rotation = np.asarray(rotation, dtype=float) if full_pose else None
        damping = self._damping[6 if full_pose else 3]
        err = np.empty(6 if full_pose else 3)
        pos_err = ori_err = math.inf
        best_error, improved_at = math.inf, 0
        for iteration in range(1, opts.max_iterations + 1):
            current_position, current_rotation, jac = robot.tcp_pose_and_jacobian(q)
            np.subtract(position, current_position, out=err[:3])
            pos_err = math.sqrt(float(err[:3] @ err[:3]))
            if target_rotation is not None:
                # error in the world-aligned TCP frame: linear part = position error, angular = log of R_err
                err[3:] = pin.log3(target_rotation @ current_rotation.T)
                ori_err = math.sqrt(float(err[3:] @ err[3:]))
                if pos_err < opts.position_tolerance_m and ori_err < opts.orientation_tolerance_rad:
                    return IkResult(True, q, pos_err, ori_err, iteration, "converged")
            else:
                ori_err = 0.0
                if pos_err < opts.position_tolerance_m:
                    return IkResult(True, q, pos_err, ori_err, iteration, "converged")
                jac = jac[:3]
            error = pos_err + ori_err * STALL_RADIUS_M
            if error < best_error * (1.0 - opts.stall_improvement):
                best_error, improved_at = error, iteration
            elif opts.stall_iterations and iteration - improved_at >= opts.stall_iterations:
                return IkResult(False, q, pos_err, ori_err, iteration, "stalled")
            dq = jac.T @ eigenpy.LLT(jac @ jac.T + damping).solve(err)
            largest = float(np.abs(dq).max())
            if largest > opts.max_step_rad:
                dq *= opts.max_step_rad / largest
            q = np.minimum(np.maximum(q + dq, lower), upper)
        return IkResult(False, q, pos_err, ori_err, opts.max_iterations, "did not converge")
