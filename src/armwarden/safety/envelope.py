"""The envelope: every static and geometric check a trajectory must pass before it may run.

Input: a timed joint trajectory. Output: an `EnvelopeReport` with violations and the figures a
human needs to judge the motion. The checks (docs/architecture.md, "Where each limit is enforced"):

- per waypoint, without kinematics (`safety.waypoints`): malformed input, joint limits (exact
  between waypoints, since the path is linear in joint space), near-limit margin, joint travel,
  peak velocity and acceleration from the waypoint timing;
- geometry, with forward kinematics at conservatively chosen samples: every checked link's
  capsule (padded) inside the workspace box and out of every keep-out box, the TCP likewise (its
  segments between samples too), and capsule pairs apart (self-collision). By default the
  geometry runs compiled (`safety.kernel`: the same samples and findings); the numpy
  passes (`safety.numpy_pass`, `compiled=False`) are its test oracle. The samples are placed by
  `safety.sampling`, the bodies and zones come from `safety.bodies`, the findings are worded by
  `safety.findings`.

**Why the sampling is a guarantee.** Moving joint i by Δq_i moves any point of body b by at most
|Δq_i| · reach[i, b] (`RobotModel.reach`), so along the path every point of b moves at most
Σ_i |Δq_i| · reach[i, b] between two samples. Samples are placed so that this bound never
exceeds `sweep_resolution_m`. Because the bound is uniform over the body and grows along the
path, at every instant between samples k and k+1 *every* point of b is within half the bound of
where it was at sample k, or every point is within half the bound of where it is at k+1. Each
body is therefore tested inflated by half the bound of the intervals next to the sample, and
nothing can slip through a zone between samples, however thin the zone or fast the motion.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.batch_fk import KinematicChain
from armwarden.robot.model import Pose, RobotModel
from armwarden.safety import waypoints
from armwarden.safety.bodies import CheckedBodies
from armwarden.safety.findings import Found, from_kernel_rows, in_time_order, report_order, time_of
from armwarden.safety.kernel import driver as kernels
from armwarden.safety.kernel.tables import HIT_COLUMNS, NON_FINITE, Tables
from armwarden.safety.limits import Box, EnvelopeLimits, EnvelopeReport
from armwarden.safety.numpy_pass import geometry_pass
from armwarden.safety.sampling import PathParameter, Samples, merged_ranges, path_parameter, samples_at, unit_targets
from armwarden.safety.violations import Code, Violation
from armwarden.safety.waypoints import ACCELERATION_TOLERANCE, estimate_accelerations, estimate_velocities

#: sample spacings of the geometry passes, in units of one sweep resolution: the first pass, then
#: each denser pass around what the one before flagged (bodies inflated to match each spacing)
REFINEMENT = (4.0, 1.0, 0.25, 0.0625)


class Envelope:
    """Checks trajectories against the limits for one robot model. Not thread safe (shares Pinocchio data).

    `compiled` (the default): the geometry runs in the numba kernels of `safety.kernel`
    — the same samples, predicates and findings as the numpy passes (`safety.numpy_pass`), ~100× faster. False:
    the numpy passes, the kernels' test oracle (tests/safety/test_geometry_kernel.py)."""

    def __init__(self, robot: RobotModel, limits: EnvelopeLimits, *, compiled: bool = True) -> None:
        self.robot = robot
        self.limits = limits
        self.bodies = CheckedBodies.build(robot, limits)
        self._kernel = self._kernel_tables() if compiled else None

    @property
    def compiled(self) -> bool:
        """Whether the geometry runs in the compiled kernels (else in the numpy passes)."""
        return self._kernel is not None

    # ------------------------------------------------------------------ set-up
    def _kernel_tables(self) -> Tables:
        """What the kernels need of this envelope: the chain of joints (the robot's own Pinocchio
        model, in the base frame), every body on its joint, the radii, pairs, reaches and boxes."""
        robot, lim = self.robot, self.limits
        model = robot.model
        base = model.frames[robot.frame_id(robot.base_frame)]
        chain = KinematicChain.from_model(model, [], None if base.placement.isIdentity() else base.placement.inverse())
        tcp = model.frames[robot.frame_id(robot.tcp_frame)]
        tcp_point = np.asarray(tcp.placement.translation, dtype=float)[None]
        capsules = robot.capsules
        return Tables.build(
            chain=chain,
            body_joint=[c.joint_index for c in capsules] + [int(tcp.parentJoint)],
            body_p0=np.vstack([np.array([c.p0_m for c in capsules], dtype=float).reshape(-1, 3), tcp_point]),
            body_p1=np.vstack([np.array([c.p1_m for c in capsules], dtype=float).reshape(-1, 3), tcp_point]),
            body_group=[c.link for c in capsules] + [self.bodies.names[-1]],
            body_name=self.bodies.names,
            report_order=partial(report_order, self.bodies),
            padded_radii=self.bodies.padded_radii,
            moving=self.bodies.moving,
            pairs=self.bodies.pairs,
            pair_radii=self.bodies.pair_radii,
            pair_sphere_reach=self.bodies.pair_sphere_reach,
            reach=robot.reach,
            pair_reach=self.bodies.pair_reach,
            workspace_lo=self.bodies.workspace_lo,
            workspace_hi=self.bodies.workspace_hi,
            keep_out_lo=self.bodies.keep_out_lo,
            keep_out_hi=self.bodies.keep_out_hi,
            lower=lim.lower_rad,
            upper=lim.upper_rad,
            sweep_resolution_m=lim.sweep_resolution_m,
            check_resolution_rad=lim.check_resolution_rad,
            joint_limit_margin_rad=lim.joint_limit_margin_rad,
            refinement=REFINEMENT,
        )

    @property
    def self_collision_pairs(self) -> list[tuple[str, str]]:
        return [(self.bodies.names[a], self.bodies.names[b]) for a, b in self.bodies.pairs]

    # ------------------------------------------------------------------ entry point
    def check(self, trajectory: JointTrajectory) -> EnvelopeReport:
        malformed = waypoints.check_malformed(trajectory, self.robot.joint_names, self.robot.nq)
        if malformed:
            return EnvelopeReport(violations=tuple(malformed))
        times, positions = trajectory.times, trajectory.positions
        violations: list[Violation] = []
        names = self.robot.joint_names
        violations += waypoints.check_joint_limits(self.limits, names, times, positions)
        travel = np.sum(np.abs(np.diff(positions, axis=0)), axis=0) if len(positions) > 1 else np.zeros(positions.shape[1])
        violations += waypoints.check_travel(self.limits, names, travel)
        vel_ratio, acc_ratio, dyn = waypoints.check_dynamics(self.limits, names, times, positions)
        violations += dyn
        geo, tcp_length, final_pose, n_samples = self._check_geometry(times, positions)
        violations += geo
        if tcp_length > self.limits.max_cartesian_step_m:
            violations.append(
                Violation(
                    Code.CARTESIAN_STEP_TOO_LARGE,
                    f"TCP path length {tcp_length:.3f} m exceeds max_cartesian_step_m {self.limits.max_cartesian_step_m:.3f} m",
                    float(times[-1]),
                    self.robot.tcp_frame,
                )
            )
        return EnvelopeReport(
            violations=tuple(violations),
            max_joint_velocity_ratio=vel_ratio,
            max_joint_acceleration_ratio=acc_ratio,
            max_joint_travel_rad=float(np.max(travel)) if travel.size else 0.0,
            tcp_path_length_m=tcp_length,
            final_tcp_pose=final_pose,
            samples_checked=n_samples,
        )

    # ------------------------------------------------------------------ for planners: the same checks, untimed
    def check_path(self, positions: np.ndarray, *, first_only: bool = False) -> tuple[Violation, ...]:
        """Joint limits and geometry of an untimed joint polyline `(K, n)` (or one configuration).

        This is what planners search with, so that they never use a second collision model: the
        same joint-limit check and the same sweep-bounded geometry pass as `check` (workspace,
        keep-out, self-collision, every padded capsule and the TCP), without what only a whole timed
        plan has (timing, travel caps, TCP path length). Violation times are waypoint indices.
        `first_only`: a search only needs to know *whether* something is hit, so the check stops
        at the first hard joint-limit finding or the first sample range with a geometric one, and
        reports that range's first geometric finding only (the findings are then incomplete, never
        fewer than one when there is any; wording one costs more than finding it).
        """
        positions = positions if type(positions) is np.ndarray else np.asarray(positions, dtype=float)
        if self._kernel is not None and 1 <= positions.ndim <= 2 and positions.shape[-1] == self.robot.nq and len(positions):
            found = self._check_path_compiled(kernels.kernel_array(positions), first_only)
            if found is not None:
                return found
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        if not np.all(np.isfinite(positions)):  # refused as such, not left to how a comparison treats NaN
            return (Violation(Code.MALFORMED, "non-finite value (NaN or Inf) in the joint path"),)
        single = len(positions) == 1
        if single:
            positions = np.vstack([positions, positions])
        index = np.arange(len(positions), dtype=float)
        violations = waypoints.check_joint_limits(self.limits, self.robot.joint_names, index, positions)
        if first_only and any(v.is_hard for v in violations):
            return tuple(violations)
        if single:  # one configuration does not move: one pass without sweep allowance is the whole check
            geometric = self._check_configuration(positions[0])
        else:
            geometric, _, _, _ = self._check_geometry(index, positions, first_only=first_only)
        return tuple(violations + (geometric[:1] if first_only else geometric))

    def _check_path_compiled(self, positions: np.ndarray, first_only: bool) -> tuple[Violation, ...] | None:
        """`check_path` in the kernels (`positions` C-contiguous (K, n), K ≥ 1, or one configuration
        (n,)): the same findings, the joint limits' built by `waypoints` only when the kernel saw
        one. None when a configuration holds a non-finite value (the numpy check says what)."""
        kernel = self._kernel
        assert kernel is not None
        hits = np.empty((kernel.hit_capacity + 1, HIT_COLUMNS))
        single = positions.ndim == 1 or len(positions) == 1
        if single:  # one configuration does not move: one pass without sweep allowance
            q = positions if positions.ndim == 1 else positions[0]
            code = kernels.check_configuration(q, 0.0, first_only, kernel.ints, kernel.floats, hits)
            if code == NON_FINITE:
                return None
            status, count = code >> 32, code & 0xFFFFFFFF
        else:
            seg_bound = np.abs(np.diff(positions, axis=0)) @ self.robot.reach
            status, count, _, _ = kernels.check_path(np.arange(len(positions), dtype=float), positions, seg_bound,
                                                     first_only, kernel.ints, kernel.floats, hits)
            if count == NON_FINITE:
                return None
        # first_only: the first finding in report order (the kernels return them in it)
        geometric = in_time_order(from_kernel_rows(self.bodies, hits[:1] if first_only else hits[:count])) if count else []
        if not status:
            return tuple(geometric)
        path = np.vstack([positions, positions]) if single else positions  # (one row or two: as the numpy check)
        limits = waypoints.check_joint_limits(self.limits, self.robot.joint_names, np.arange(len(path), dtype=float), path)
        if first_only and any(v.is_hard for v in limits):
            return tuple(limits)
        return tuple(limits + geometric)

    def _check_configuration(self, q: np.ndarray, allowance_m: float = 0.0) -> list[Violation]:
        """The geometry of one configuration: what `_check_geometry` finds for a path that stays
        there (its samples all sit at `q`, their sweep allowance is zero, so coarse and fine
        passes see the same), in one pass instead of a coarse and a fine one. `allowance_m`
        inflates every body (not the self-collision pairs) as a sweep allowance would."""
        kernel = self._kernel
        if kernel is not None and q.shape == (self.robot.nq,):
            hits = np.empty((kernel.hit_capacity + 1, HIT_COLUMNS))
            code = kernels.check_configuration(kernels.kernel_array(q), float(allowance_m), False,
                                               kernel.ints, kernel.floats, hits)
            if code != NON_FINITE:
                return in_time_order(from_kernel_rows(self.bodies, hits[:code & 0xFFFFFFFF]))
        samples = Samples(times=np.zeros(1), positions=q[None],
                          inflation=np.full((1, len(self.bodies.padded_radii)), float(allowance_m)),
                          pair_inflation=np.zeros((1, len(self.bodies.pairs))))
        found, _, _ = self._geometry_pass(samples)
        return in_time_order(found)

    def check_arrival(self, q: np.ndarray, share: float) -> tuple[Violation, ...]:
        """Keep-out zones and the workspace box at `q` with every body grown by `share` ×
        `sweep_resolution_m` (self-collision is not checked with growth: the pairs get none), every
        finding. The final check grows each body at a plan's last sample by half its motion bound
        over the sampling interval before it, and no body moves more than `sweep_resolution_m` in
        one interval, so a configuration clear here with share 0.5 is never refused, as a plan's
        last sample, for a zone or the workspace edge (the motion into it still may be, and
        self-collision pairs get their own allowance).
        How much less a body gets depends on the motion into `q` (one that barely moves gets almost
        none), so with a smaller share this is a likelihood, not a verdict: planners rank goals with
        it (`planning.goals`), and the final check is unchanged."""
        return tuple(self._check_configuration(np.asarray(q, dtype=float), share * self.limits.sweep_resolution_m))

    # ------------------------------------------------------------------ geometry
    def _path_parameter(self, times: np.ndarray, positions: np.ndarray) -> PathParameter:
        """The path parameter of a waypoint polyline under these limits (`sampling.path_parameter`)."""
        return path_parameter(times, positions, self.robot.reach, self.bodies.pair_reach,
                              self.limits.sweep_resolution_m, self.limits.check_resolution_rad)

    def sample_path(self, times: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fine conservative samples along the whole path: times (N,), configurations (N, n) and
        per-sample, per-body inflation (N, B+1; the TCP point last)."""
        path = self._path_parameter(times, positions)
        samples = samples_at(path, unit_targets(0.0, path.total))
        return samples.times, samples.positions, samples.inflation

    def _check_geometry(self, times: np.ndarray, positions: np.ndarray,
                        first_only: bool = False) -> tuple[list[Violation], float, Pose, int]:
        """Coarse to fine: a pass with samples `REFINEMENT[0]` units apart (bodies inflated by
        half the motion bound of their intervals, so a clean pass is as much a proof as a denser
        one); where a pass finds anything, the path around those samples is checked again with
        samples the next spacing apart, and so on; only the densest level's findings are reported.
        Plans far from every zone cost a fraction of one fine pass, and a body that passes a few
        millimetres from a surface (fingers over the table) is not refused for the sweep
        allowance of a sparse sampling: the allowance shrinks with the spacing where it matters."""
        kernel = self._kernel
        if kernel is not None and positions.ndim == 2 and positions.shape[1] == self.robot.nq and len(positions) >= 2:
            hits = np.empty((kernel.hit_capacity + 1, HIT_COLUMNS))
            seg_bound = np.abs(np.diff(positions, axis=0)) @ self.robot.reach
            _, count, checked, tcp = kernels.check_path(
                kernels.kernel_array(times), kernels.kernel_array(positions), seg_bound, first_only,
                kernel.ints, kernel.floats, hits)
            if count != NON_FINITE:
                tcp_length = float(np.sum(np.linalg.norm(np.diff(tcp, axis=0), axis=1))) if len(tcp) > 1 else 0.0
                found = in_time_order(from_kernel_rows(self.bodies, hits[:count]))
                return found, tcp_length, self.robot.tcp_pose(positions[-1]), checked
        path = self._path_parameter(times, positions)
        targets = unit_targets(0.0, path.total, REFINEMENT[0])
        samples = samples_at(path, targets)
        found, flagged, tcp = self._geometry_pass(samples)
        checked = len(samples.times)
        if np.any(flagged):
            found, checked_densely = self._refine(path, targets, samples, flagged, 1, first_only)
            checked += checked_densely
        tcp_length = float(np.sum(np.linalg.norm(np.diff(tcp, axis=0), axis=1))) if len(tcp) > 1 else 0.0
        return in_time_order(found), tcp_length, self.robot.tcp_pose(positions[-1]), checked

    def _refine(self, path: PathParameter, targets: np.ndarray, samples: Samples, flagged: np.ndarray, level: int,
                first_only: bool) -> tuple[Found, int]:
        """Findings around the flagged samples of a pass at `REFINEMENT[level - 1]`.

        A flagged sample whose configuration violates by itself (without any sweep allowance) is
        a finding as it stands: no sampling could clear it. Around the others — flagged only
        because of their allowance — the path is checked again at `REFINEMENT[level]` and, where
        that flags again, denser still (depth first, so a search's `first_only` stops at the
        first finding). Only what the densest check of a stretch finds is reported."""
        checked = 0
        k = np.flatnonzero(flagged)
        still = Samples(samples.times[k], samples.positions[k], np.zeros_like(samples.inflation[k]),
                        np.zeros_like(samples.pair_inflation[k]))
        found, certain, _ = self._geometry_pass(still, segments=False)  # each a configuration by itself
        checked += len(k)
        if first_only and found:
            return found, checked
        for start, end in merged_ranges(targets, k[~certain]):
            dense_targets = unit_targets(start, end, REFINEMENT[level])
            dense = samples_at(path, dense_targets)
            dense_found, dense_flagged, _ = self._geometry_pass(dense)
            checked += len(dense.times)
            if level + 1 < len(REFINEMENT) and np.any(dense_flagged):
                dense_found, deeper = self._refine(path, dense_targets, dense, dense_flagged, level + 1, first_only)
                checked += deeper
            for key, violation in dense_found.items():
                if key not in found or time_of(violation) < time_of(found[key]):
                    found[key] = violation
            if first_only and found:
                break
        return found, checked

    def _geometry_pass(self, samples: Samples, segments: bool = True
                       ) -> tuple[Found, np.ndarray, np.ndarray]:
        """One check of consecutive samples. Returns the first violation per (code, body, what)
        — per body name its earliest sample's (at it, the lowest-indexed body's) —, which samples
        found anything, and the TCP positions. Every keep-out candidate of the broad phase is
        confirmed exactly. In the kernels, else in numpy (`numpy_pass`). `segments`: the TCP's straight segment from
        the sample before counts too (False: the samples are separate configurations)."""
        kernel = self._kernel
        if kernel is not None and samples.positions.ndim == 2 and samples.positions.shape[1] == self.robot.nq:
            n = len(samples.times)
            flags = np.zeros(n, dtype=bool)
            tcp = np.empty((n, 3))
            hits = np.empty((kernel.hit_capacity + 1, HIT_COLUMNS))
            count = kernels.check_samples(
                kernels.kernel_array(samples.times), kernels.kernel_array(samples.positions),
                kernels.kernel_array(samples.inflation),
                kernels.kernel_array(samples.pair_inflation.reshape(n, len(self.bodies.pairs))), segments,
                kernel.ints, kernel.floats, flags, tcp, hits)
            if count != NON_FINITE:
                return from_kernel_rows(self.bodies, hits[:count]), flags, tcp
        return geometry_pass(self.robot, self.bodies, samples, segments)


__all__ = [  # with the per-waypoint estimates, which the planner's timing verifies against too
    "ACCELERATION_TOLERANCE",
    "REFINEMENT",
    "Box",
    "Envelope",
    "EnvelopeLimits",
    "EnvelopeReport",
    "estimate_accelerations",
    "estimate_velocities",
]
