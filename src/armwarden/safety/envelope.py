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
  passes below (`compiled=False`) are its test oracle.

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

from dataclasses import dataclass

import numpy as np

from armwarden.core import geometry
from armwarden.core.errors import RobotModelError
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.batch_fk import KinematicChain
from armwarden.robot.model import Pose, RobotModel
from armwarden.safety import waypoints
from armwarden.safety.kernel import driver as kernels
from armwarden.safety.kernel.tables import HIT_COLUMNS, KIND_SELF, KIND_WORKSPACE, NON_FINITE, Tables
from armwarden.safety.limits import Box, EnvelopeLimits, EnvelopeReport
from armwarden.safety.violations import Code, Violation
from armwarden.safety.waypoints import ACCELERATION_TOLERANCE, estimate_accelerations, estimate_velocities

#: sample spacings of the geometry passes, in units of one sweep resolution: the first pass, then
#: each denser pass around what the one before flagged (bodies inflated to match each spacing)
REFINEMENT = (4.0, 1.0, 0.25, 0.0625)


class Envelope:
    """Checks trajectories against the limits for one robot model. Not thread safe (shares Pinocchio data).

    `compiled` (the default): the geometry runs in the numba kernels of `safety.kernel`
    — the same samples, predicates and findings as the numpy passes here, ~100× faster. False:
    the numpy passes, the kernels' test oracle (tests/safety/test_geometry_kernel.py)."""

    def __init__(self, robot: RobotModel, limits: EnvelopeLimits, *, compiled: bool = True) -> None:
        self.robot = robot
        self.limits = limits
        self._body_names = [_body_name(robot, c) for c in robot.capsules]
        # the TCP point is the last body (zero radius, no padding); a TCP frame that is also a link
        # with bodies of its own (`tcp_frame: fr3_hand`) is told apart from that link's bodies
        self._body_names.append(robot.tcp_frame if robot.tcp_frame not in self._body_names else f"{robot.tcp_frame} (TCP)")
        unknown = sorted(set(limits.padding_by_link_m) - set(robot.link_names()))
        if unknown:
            raise RobotModelError(f"padding_by_link_m names unknown link(s) {unknown}; valid links: {sorted(robot.link_names())}")
        padding = [limits.padding_by_link_m.get(c.link, limits.link_padding_m) for c in robot.capsules]
        self._padded_radii = np.concatenate([robot.capsule_radii + np.array(padding, dtype=float), [0.0]])
        # bodies fixed to the world (the base) cannot move into a zone or out of the box: only
        # self-collision looks at them (the TCP point, last, always moves with the arm)
        self._moving = np.array([c.joint_index != 0 for c in robot.capsules] + [True])
        self._pairs = robot.self_collision_pairs if limits.self_collision else np.zeros((0, 2), dtype=np.intp)
        self._pair_radii = robot.capsule_radii[self._pairs[:, 0]] + robot.capsule_radii[self._pairs[:, 1]]
        self._pair_reach = self._relative_reach()
        half_lengths = np.array([np.linalg.norm(np.subtract(c.p1_m, c.p0_m)) / 2.0 for c in robot.capsules])
        self._pair_sphere_reach = self._pair_radii + half_lengths[self._pairs[:, 0]] + half_lengths[self._pairs[:, 1]]
        self._ws_lo = limits.workspace.lo
        self._ws_hi = limits.workspace.hi
        names = [z.name for z in limits.keep_out]
        if len(set(names)) != len(names):  # the policy refuses it too: findings name their zone
            raise ValueError(f"keep-out zone names must be unique; got {names}")
        if limits.keep_out:
            self._ko_lo = np.stack([z.lo for z in limits.keep_out])
            self._ko_hi = np.stack([z.hi for z in limits.keep_out])
        else:
            self._ko_lo = self._ko_hi = np.zeros((0, 3))
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
            body_group=[c.link for c in capsules] + [self._body_names[-1]],
            body_name=self._body_names,
            report_order=self._report_order,
            padded_radii=self._padded_radii,
            moving=self._moving,
            pairs=self._pairs,
            pair_radii=self._pair_radii,
            pair_sphere_reach=self._pair_sphere_reach,
            reach=robot.reach,
            pair_reach=self._pair_reach,
            workspace_lo=self._ws_lo,
            workspace_hi=self._ws_hi,
            keep_out_lo=self._ko_lo,
            keep_out_hi=self._ko_hi,
            lower=lim.lower_rad,
            upper=lim.upper_rad,
            sweep_resolution_m=lim.sweep_resolution_m,
            check_resolution_rad=lim.check_resolution_rad,
            joint_limit_margin_rad=lim.joint_limit_margin_rad,
            refinement=REFINEMENT,
        )

    def _report_order(self, kind: int, subject: str, zone: int) -> tuple[str, str, str]:
        """How `_in_time_order` orders findings of one time, for the kernels: by code, body, then
        the wording after the body's name (for one body, its zones by name)."""
        if kind == KIND_SELF:
            return _SELF_COLLISION, subject, ""
        if kind == KIND_WORKSPACE:
            return Code.WORKSPACE.value, subject, f" {_LEAVES_WORKSPACE} near ("
        return Code.KEEP_OUT.value, subject, f" {_enters(self.limits.keep_out[zone])} near ("

    def _relative_reach(self) -> np.ndarray:
        """`(n, P)`: bound on how far the distal capsule of each pair moves *relative to the other*
        per unit motion of each joint. Only the joints between the two capsules move one relative
        to the other, so pairs near the base get far smaller allowances than the sum of both
        capsules' absolute motions. Capsules on separate branches keep the sum (conservative)."""
        model, capsules, reach = self.robot.model, self.robot.capsules, self.robot.reach
        out = np.zeros((self.robot.nq, len(self._pairs)))
        for index, (a, b) in enumerate(self._pairs):
            ja, jb = capsules[a].joint_index, capsules[b].joint_index
            if ja > jb:
                a, b, ja, jb = b, a, jb, ja
            chain, j = set(), jb
            while j > 0:
                chain.add(j)
                j = model.parents[j]
            if ja == 0 or ja in chain:
                between = [model.joints[j].idx_q for j in chain if j > ja]
                out[between, index] = reach[between, b]
            else:
                out[:, index] = reach[:, a] + reach[:, b]
        return out

    @property
    def self_collision_pairs(self) -> list[tuple[str, str]]:
        return [(self._body_names[a], self._body_names[b]) for a, b in self._pairs]

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
        geometric = _in_time_order(self._findings(hits[:1] if first_only else hits[:count])) if count else []
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
                return _in_time_order(self._findings(hits[:code & 0xFFFFFFFF]))
        samples = _Samples(times=np.zeros(1), positions=q[None],
                           inflation=np.full((1, len(self._padded_radii)), float(allowance_m)),
                           pair_inflation=np.zeros((1, len(self._pairs))))
        found, _, _ = self._geometry_pass(samples)
        return _in_time_order(found)

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
    def _path_parameter(self, times: np.ndarray, positions: np.ndarray) -> _PathParameter:
        """Cumulative sampling cost along the waypoint polyline, in units of one fine interval.

        A segment's cost is its point-motion bound against `sweep_resolution_m` or its largest
        joint step against `check_resolution_rad`, whichever is larger; samples one unit apart
        satisfy both. `body` holds the cumulative per-body motion bound [m] (TCP last).
        """
        steps = np.abs(np.diff(positions, axis=0))
        seg_bound = steps @ self.robot.reach  # (K-1, B+1)
        cost = np.maximum(
            np.max(seg_bound, axis=1) / self.limits.sweep_resolution_m,
            np.max(steps, axis=1) / self.limits.check_resolution_rad,
        )
        pair_bound = steps @ self._pair_reach  # (K-1, P)
        return _PathParameter(
            times=times,
            positions=positions,
            cost=np.concatenate([[0.0], np.cumsum(cost)]),
            body=np.vstack([np.zeros((1, seg_bound.shape[1])), np.cumsum(seg_bound, axis=0)]),
            pairs=np.vstack([np.zeros((1, pair_bound.shape[1])), np.cumsum(pair_bound, axis=0)]),
        )

    def _samples_at(self, path: _PathParameter, targets: np.ndarray) -> _Samples:
        """Times, configurations and inflations of samples at path-parameter `targets`.

        The inflation of a sample is half the larger motion bound of the intervals next to it
        (within this run of samples): per body, and per self-collision pair (relative motion).
        """
        cum = path.cost
        k = np.clip(np.searchsorted(cum, targets, side="left") - 1, 0, len(cum) - 2)
        span = cum[k + 1] - cum[k]
        alpha = np.clip(np.where(span > 0, (targets - cum[k]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)
        at_end = targets >= cum[-1]

        def at(values: np.ndarray) -> np.ndarray:
            sampled = values[k] + (alpha[:, None] if values.ndim == 2 else alpha) * (values[k + 1] - values[k])
            sampled[at_end] = values[-1]
            return sampled

        return _Samples(
            times=at(path.times),
            positions=at(path.positions),
            inflation=_half_neighbour_bound(at(path.body)),
            pair_inflation=_half_neighbour_bound(at(path.pairs)),
        )

    def sample_path(self, times: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fine conservative samples along the whole path: times (N,), configurations (N, n) and
        per-sample, per-body inflation (N, B+1; the TCP point last)."""
        path = self._path_parameter(times, positions)
        samples = self._samples_at(path, _unit_targets(0.0, path.total))
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
                found = _in_time_order(self._findings(hits[:count]))
                return found, tcp_length, self.robot.tcp_pose(positions[-1]), checked
        path = self._path_parameter(times, positions)
        targets = _unit_targets(0.0, path.total, REFINEMENT[0])
        samples = self._samples_at(path, targets)
        found, flagged, tcp = self._geometry_pass(samples)
        checked = len(samples.times)
        if np.any(flagged):
            found, checked_densely = self._refine(path, targets, samples, flagged, 1, first_only)
            checked += checked_densely
        tcp_length = float(np.sum(np.linalg.norm(np.diff(tcp, axis=0), axis=1))) if len(tcp) > 1 else 0.0
        return _in_time_order(found), tcp_length, self.robot.tcp_pose(positions[-1]), checked

    def _refine(self, path: _PathParameter, targets: np.ndarray, samples: _Samples, flagged: np.ndarray, level: int,
                first_only: bool) -> tuple[dict[tuple[str, str, str], Violation], int]:
        """Findings around the flagged samples of a pass at `REFINEMENT[level - 1]`.

        A flagged sample whose configuration violates by itself (without any sweep allowance) is
        a finding as it stands: no sampling could clear it. Around the others — flagged only
        because of their allowance — the path is checked again at `REFINEMENT[level]` and, where
        that flags again, denser still (depth first, so a search's `first_only` stops at the
        first finding). Only what the densest check of a stretch finds is reported."""
        checked = 0
        k = np.flatnonzero(flagged)
        still = _Samples(samples.times[k], samples.positions[k], np.zeros_like(samples.inflation[k]),
                         np.zeros_like(samples.pair_inflation[k]))
        found, certain, _ = self._geometry_pass(still, segments=False)  # each a configuration by itself
        checked += len(k)
        if first_only and found:
            return found, checked
        for start, end in _merged_ranges(targets, k[~certain]):
            dense_targets = _unit_targets(start, end, REFINEMENT[level])
            dense = self._samples_at(path, dense_targets)
            dense_found, dense_flagged, _ = self._geometry_pass(dense)
            checked += len(dense.times)
            if level + 1 < len(REFINEMENT) and np.any(dense_flagged):
                dense_found, deeper = self._refine(path, dense_targets, dense, dense_flagged, level + 1, first_only)
                checked += deeper
            for key, violation in dense_found.items():
                if key not in found or _time_of(violation) < _time_of(found[key]):
                    found[key] = violation
            if first_only and found:
                break
        return found, checked

    def _geometry_pass(self, samples: _Samples, segments: bool = True
                       ) -> tuple[dict[tuple[str, str, str], Violation], np.ndarray, np.ndarray]:
        """One check of consecutive samples. Returns the first violation per (code, body, what)
        — per body name its earliest sample's (at it, the lowest-indexed body's) —, which samples
        found anything, and the TCP positions. Every keep-out candidate of the broad phase is
        confirmed exactly (`_confirm_keep_out`). `segments`: the TCP's straight segment from
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
                kernels.kernel_array(samples.pair_inflation.reshape(n, len(self._pairs))), segments,
                kernel.ints, kernel.floats, flags, tcp, hits)
            if count != NON_FINITE:
                return self._findings(hits[:count]), flags, tcp
        robot, lim = self.robot, self.limits
        t_s, q_s, inflation = samples.times, samples.positions, samples.inflation
        p0, p1 = robot.body_points(robot.joint_frames(q_s))  # (N, B+1, 3); last body is the TCP point
        tcp = p0[:, -1]
        radius = inflation + self._padded_radii  # (N, B+1)
        found: dict[tuple[str, str, str], Violation] = {}
        flagged = np.zeros(len(t_s), dtype=bool)

        # axis-aligned bounds of every padded, inflated capsule: the broad phase for everything below
        lo, hi = geometry.capsule_bounds(p0, p1, radius)

        # workspace: every capsule and the TCP entirely inside the box (exact for capsules)
        outside = ~geometry.bounds_inside(lo, hi, self._ws_lo, self._ws_hi) & self._moving
        flagged |= np.any(outside, axis=1)
        self._first_per_body(found, outside, t_s, p0, Code.WORKSPACE, _LEAVES_WORKSPACE)

        # keep-out: bounds that overlap a zone are confirmed exactly (capsule–box distance)
        if len(lim.keep_out):
            overlap = np.all(lo[:, :, None] <= self._ko_hi, axis=-1) & np.all(hi[:, :, None] >= self._ko_lo, axis=-1)
            overlap &= self._moving[None, :, None]
            if segments and len(tcp) > 1:  # the TCP's straight segments between samples, too
                r_tcp = radius[1:, -1, None]
                seg_lo = np.minimum(tcp[:-1], tcp[1:]) - r_tcp
                seg_hi = np.maximum(tcp[:-1], tcp[1:]) + r_tcp
                overlap[1:, -1] |= np.all(seg_lo[:, None] <= self._ko_hi, axis=-1) & np.all(seg_hi[:, None] >= self._ko_lo, axis=-1)
            if np.any(overlap):
                confirmed = self._confirm_keep_out(overlap, p0, p1, radius, tcp, segments)
                flagged |= np.any(confirmed, axis=(1, 2))
                for zone_index, zone in enumerate(lim.keep_out):
                    self._first_per_body(found, confirmed[:, :, zone_index], t_s, p0, Code.KEEP_OUT, _enters(zone))

        # self-collision: capsule pairs closer than the sum of their inflated radii
        if len(self._pairs):
            flagged |= self._check_self_collision(found, t_s, p0, p1, samples.pair_inflation)
        return found, flagged, tcp

    def _confirm_keep_out(self, overlap: np.ndarray, p0: np.ndarray, p1: np.ndarray, radius: np.ndarray,
                          tcp: np.ndarray, segments: bool) -> np.ndarray:
        """Exact test of the broad-phase candidates, all at once: each capsule's distance to the
        zone against its radius, and for the TCP also (`segments`) its straight segment from the
        previous sample."""
        confirmed = np.zeros_like(overlap)
        k, body, zone = np.nonzero(overlap)
        zone_lo, zone_hi, r = self._ko_lo[zone], self._ko_hi[zone], radius[k, body]
        hit = geometry.segment_box_distance(p0[k, body], p1[k, body], zone_lo, zone_hi) <= r
        segment = ~hit & (body == radius.shape[1] - 1) & (k > 0) & segments  # the TCP, between samples
        if np.any(segment):
            ks, rs = k[segment], r[segment, None]
            hit[segment] = geometry.segments_hit_boxes(tcp[ks - 1], tcp[ks], zone_lo[segment] - rs, zone_hi[segment] + rs)
        confirmed[k, body, zone] = hit
        return confirmed

    def _check_self_collision(
        self, found: dict, t_s: np.ndarray, p0: np.ndarray, p1: np.ndarray, pair_inflation: np.ndarray
    ) -> np.ndarray:
        """Adds the first self-collision per pair to `found`; returns which samples had one."""
        a, b = self._pairs[:, 0], self._pairs[:, 1]
        # broad phase: bounding spheres of the capsules (centre, half length + radius + inflation)
        centers = (p0[:, :-1] + p1[:, :-1]) / 2.0
        gap = centers[:, a] - centers[:, b]
        center_distance = np.sqrt(np.einsum("npi,npi->np", gap, gap))
        candidates = center_distance < self._pair_sphere_reach + pair_inflation  # (N, P)
        flagged = np.zeros(len(t_s), dtype=bool)
        if not np.any(candidates):
            return flagged
        k_idx, pair_idx = np.nonzero(candidates)
        pa, pb = a[pair_idx], b[pair_idx]
        dist = geometry.segment_segment_distance(p0[k_idx, pa], p1[k_idx, pa], p0[k_idx, pb], p1[k_idx, pb])
        allowed = self._pair_radii[pair_idx] + pair_inflation[k_idx, pair_idx]
        touching = dist < allowed
        flagged[k_idx[touching]] = True
        for i in np.flatnonzero(touching):  # sorted by sample, so the first hit per pair comes first
            pair = int(pair_idx[i])
            name_a, name_b = self._body_names[a[pair]], self._body_names[b[pair]]
            key = (Code.SELF_COLLISION.value, f"{name_a}|{name_b}", "")
            if key in found:
                continue
            found[key] = self._self_collision(pair, float(dist[i]), float(allowed[i]), float(t_s[k_idx[i]]))
        return flagged

    def _self_collision(self, pair: int, distance: float, allowance: float, time: float) -> Violation:
        name_a, name_b = self._body_names[self._pairs[pair, 0]], self._body_names[self._pairs[pair, 1]]
        radii = self._pair_radii[pair]
        return Violation(
            Code.SELF_COLLISION,
            f"{name_a} and {name_b} come within {distance - radii:.3f} m of each other "
            f"(capsule surfaces, before the {allowance - radii:.3f} m sweep allowance)",
            time,
            f"{name_a}|{name_b}",
        )

    def _findings(self, hits: np.ndarray) -> dict[tuple[str, str, str], Violation]:
        """The kernels' finding rows (`kernel.tables.HIT_COLUMNS`) as the numpy passes key and word them."""
        found: dict[tuple[str, str, str], Violation] = {}
        for kind, index, zone, time, x, y, z, distance, allowance, _ in hits.tolist():
            if kind == KIND_SELF:
                violation = self._self_collision(int(index), distance, allowance, time)
                found[(_SELF_COLLISION, violation.body or "", "")] = violation
                continue
            if kind == KIND_WORKSPACE:
                code, what = Code.WORKSPACE, _LEAVES_WORKSPACE
            else:
                code, what = Code.KEEP_OUT, _enters(self.limits.keep_out[int(zone)])
            name = self._body_names[int(index)]
            found[(code.value, name, what)] = Violation(code, f"{name} {what} near ({x:.3f}, {y:.3f}, {z:.3f})", time, name)
        return found

    def _first_per_body(self, found: dict, mask: np.ndarray, t_s: np.ndarray, where: np.ndarray, code: Code, what: str) -> None:
        """Adds to `found` one violation per body name: the first sample at which `mask` is set for
        any body of that name (a fitted link's capsules share it), at it the lowest-indexed body."""
        for k, body in zip(*np.nonzero(mask), strict=True):  # by sample, then body
            name = self._body_names[body]
            key = (code.value, name, what)
            if key in found:
                continue
            found[key] = Violation(code, f"{name} {what} near {_fmt(where[k, body])}", float(t_s[k]), name)


@dataclass(frozen=True)
class _PathParameter:
    times: np.ndarray
    positions: np.ndarray
    cost: np.ndarray  # (K,) cumulative sampling cost at each waypoint
    body: np.ndarray  # (K, B+1) cumulative per-body motion bound [m]
    pairs: np.ndarray  # (K, P) cumulative relative-motion bound of each self-collision pair [m]

    @property
    def total(self) -> float:
        return float(self.cost[-1])


@dataclass(frozen=True)
class _Samples:
    times: np.ndarray  # (N,)
    positions: np.ndarray  # (N, n)
    inflation: np.ndarray  # (N, B+1) per body [m], the TCP point last
    pair_inflation: np.ndarray  # (N, P) per self-collision pair [m]


#: what the findings say, in the numpy passes and from the kernels' rows alike
_LEAVES_WORKSPACE = "leaves the workspace box"
_SELF_COLLISION = Code.SELF_COLLISION.value


def _enters(zone: Box) -> str:
    return f"enters keep-out zone '{zone.name}'"


def _in_time_order(found: dict[tuple[str, str, str], Violation]) -> list[Violation]:
    """The findings of geometry passes, earliest first, then by code, body and wording: one order
    however the passes met them."""
    if len(found) < 2:
        return list(found.values())
    return sorted(found.values(), key=lambda v: (_time_of(v), v.code.value, v.body or "", v.detail))


def _half_neighbour_bound(cumulative: np.ndarray) -> np.ndarray:
    """Per sample: half the larger of the bounds of the two intervals next to it."""
    interval = np.diff(cumulative, axis=0)
    if not len(interval):
        return np.zeros_like(cumulative)
    return np.maximum(np.vstack([interval[:1], interval]), np.vstack([interval, interval[-1:]])) / 2.0


def _unit_targets(start: float, end: float, spacing: float = 1.0) -> np.ndarray:
    """Evenly spaced path-parameter targets from `start` to `end`, at most `spacing` apart."""
    n_intervals = max(1, int(np.ceil((end - start) / spacing - 1e-12))) if end > start else 1
    return np.linspace(start, end, n_intervals + 1)


def _time_of(violation: Violation) -> float:
    """When a geometric finding happened (one without a time counts as at the start)."""
    return violation.time_s if violation.time_s is not None else 0.0


def _merged_ranges(targets: np.ndarray, flagged: np.ndarray) -> list[tuple[float, float]]:
    """Path ranges [target[k-1], target[k+1]] around every flagged sample k, overlaps merged."""
    ranges: list[tuple[float, float]] = []
    for k in flagged:
        start, end = float(targets[max(k - 1, 0)]), float(targets[min(k + 1, len(targets) - 1)])
        if ranges and start <= ranges[-1][1]:
            ranges[-1] = (ranges[-1][0], max(ranges[-1][1], end))
        else:
            ranges.append((start, end))
    return ranges


def _body_name(robot: RobotModel, capsule) -> str:
    """How findings name a body: its link, or `link#capsule` when the link has several primitives
    from the URDF. Fitted bodies (`link/k`) are named by their link: they are pieces of one
    surface, and a finding per link (its first) is what a person reads."""
    if capsule.name.startswith(f"{capsule.link}/"):
        return capsule.link
    if sum(1 for c in robot.capsules if c.link == capsule.link) > 1:
        return f"{capsule.link}#{capsule.name}"
    return capsule.link


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in p) + ")"


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
