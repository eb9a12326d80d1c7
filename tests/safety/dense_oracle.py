"""An independent checker of the sweep guarantee, shared by the envelope's and the planners' tests.

It shares no code with the envelope's sampling: Pinocchio's own joint placements (each capsule's
end points carried by its joint's `oMi`) and coal's collision tests, at samples resampled until no
capsule end point moves more than 1 mm.
"""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin

from armwarden.core.trajectory import JointTrajectory
from armwarden.robot import RobotModel
from armwarden.safety.limits import EnvelopeLimits
from tests.safety.coal_shapes import coal_capsule


class DenseOracle:
    """An independent checker: Pinocchio joint placements + coal, resampled until no capsule
    end point moves more than 1 mm between samples (so no point of any capsule does)."""

    def __init__(self, robot: RobotModel, limits: EnvelopeLimits, pairs: list[tuple[int, int]] = ()) -> None:
        self.robot, self.limits, self.pairs = robot, limits, list(pairs)
        self.data = robot.model.createData()
        base = robot.model.frames[robot.model.getFrameId(robot.base_frame)]
        self.base_from_world = base.placement.inverse()

    def _segments(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, float]]:
        pin.forwardKinematics(self.robot.model, self.data, q)
        out = []
        for capsule in self.robot.capsules:
            placement = self.base_from_world * self.data.oMi[capsule.joint_index]
            out.append((placement.act(np.array(capsule.p0_m)), placement.act(np.array(capsule.p1_m)), capsule.radius_m))
        return out

    def violations(self, trajectory: JointTrajectory) -> list[str]:
        found = []
        t, t_end = 0.0, trajectory.duration_s
        dt = 1e-3
        previous = self._segments(trajectory.sample(0.0))
        self._check(previous, found, 0.0)
        while t < t_end and not found:
            step = dt
            while True:
                candidate = self._segments(trajectory.sample(min(t + step, t_end)))
                moved = max(max(np.linalg.norm(a0 - b0), np.linalg.norm(a1 - b1))
                            for (a0, a1, _), (b0, b1, _) in zip(previous, candidate, strict=True))
                if moved <= 1e-3 or step < 1e-7:
                    break
                step /= 2
            t = min(t + step, t_end)
            previous = candidate
            self._check(candidate, found, t)
            dt = step * 2
        return found

    def _check(self, segments, found: list[str], t: float) -> None:
        ws = self.limits.workspace
        # coal decides every contact; pairs whose bounding balls (centre, half length + radius) are
        # apart cannot touch and are skipped, which keeps hundreds of pairs affordable per sample
        centres = np.array([(p0 + p1) / 2.0 for p0, p1, _ in segments])
        reach = np.array([np.linalg.norm(p1 - p0) / 2.0 + r for p0, p1, r in segments])
        for a, b in self.pairs:
            if np.linalg.norm(centres[a] - centres[b]) > reach[a] + reach[b] + 1e-9:
                continue
            (a0, a1, ra), (b0, b1, rb) = segments[a], segments[b]
            shape_a, tf_a = coal_capsule(a0, a1, ra)
            shape_b, tf_b = coal_capsule(b0, b1, rb)
            result = coal.CollisionResult()
            coal.collide(shape_a, tf_a, shape_b, tf_b, coal.CollisionRequest(), result)
            if result.isCollision():
                found.append(f"{self.robot.capsules[a].name} touches {self.robot.capsules[b].name} at t={t:.4f}")
        for (p0, p1, radius), capsule in zip(segments, self.robot.capsules, strict=True):
            if capsule.joint_index == 0:
                continue  # fixed to the world: only self-collision concerns it
            r = radius + self.limits.padding_by_link_m.get(capsule.link, self.limits.link_padding_m)
            if np.any(np.minimum(p0, p1) - r < ws.lo) or np.any(np.maximum(p0, p1) + r > ws.hi):
                found.append(f"{capsule.name} outside the box at t={t:.4f}")
            if self.limits.keep_out and not any(
                np.all(np.minimum(p0, p1) - r <= zone.hi) and np.all(np.maximum(p0, p1) + r >= zone.lo)
                for zone in self.limits.keep_out
            ):
                continue  # its bounding box meets no zone
            length = float(np.linalg.norm(p1 - p0))
            z = (p1 - p0) / length
            x = np.cross([1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0], z)
            x /= np.linalg.norm(x)
            tf = coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), (p0 + p1) / 2)
            for zone in self.limits.keep_out:
                result = coal.CollisionResult()
                coal.collide(
                    coal.Capsule(r, length), tf, coal.Box(*(zone.hi - zone.lo)),
                    coal.Transform3s(np.eye(3), (zone.lo + zone.hi) / 2), coal.CollisionRequest(), result,
                )
                if result.isCollision():
                    found.append(f"{capsule.name} inside {zone.name} at t={t:.4f}")
