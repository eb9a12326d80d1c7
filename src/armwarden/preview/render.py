"""The plan preview picture attached to every `PlanSummary`, for the human who approves the plan.

Two panels side by side, in the robot base frame: a TOP view (x right, y up) and a SIDE view
(x right, z up), both at the same scale. Each shows the workspace box, the keep-out zones
(semi-transparent red, named), the links swept along the plan (light grey capsules at a few
evenly spaced instants), the TCP path (green dot at the start, blue dot at the goal), the robot
base, and a red X wherever a violation with a time was found. The title line gives the status,
duration and TCP path length.

Cheap enough to stay on by default (issue 13: ≤ 3 ms p95 for a typical plan). `PlanPreviewer`
keeps, per policy, the static scene of each picture scale it has drawn (every plan inside the
workspace box has the same one): the frames, ticks, labels and scale bars, the picture with the
zones and the base and no plan, and, for each of the sweep's three colours, how a pixel of that
colour looks under the zones, their names, the workspace outline and the base. A plan then costs
its forward kinematics (the TCP alone for the path), its title (words and digits pasted from
stamps rendered once), the sweep's masks (computed in NumPy, one capsule drawing pass, no
per-sample image filters) chosen pixel by pixel from those layers, the path and marks, and the
PNG: the picture is drawn straight into a NumPy array (`images.rgbx_image`), which the encoder
compares with the plan-less picture and compresses only in the row bands the plan drew on,
without per-row filter search (`images.BandedPngEncoder`). Per picture, Pillow allocates no
image memory of its own: the masks and the canvas are NumPy arrays it draws into.

Pillow is a core dependency; in a broken install without it the renderer returns None (and
`armwarden serve` names the pictures lost at start-up). The output is
deterministic: the same inputs give the same bytes (Pillow's built-in default font, no
timestamps or other metadata in the PNG).

Modules: this one holds the previewer and the plan's geometry and strokes; `scene` the static
scene of each scale, `sweep` the swept links, `palette` the colours, `images` the NumPy-backed
images and the PNG encoder.

Threads: a previewer draws one picture at a time (every picture of a scene is drawn on that
scene's one canvas, under a lock), but it runs forward kinematics on the `robot` it is given,
whose Pinocchio data is not thread safe: call it wherever that robot model is otherwise used
(the Guard's planning thread).
"""

from __future__ import annotations

import math
import threading
from typing import TYPE_CHECKING, Any

import numpy as np

from armwarden.preview import palette
from armwarden.preview.images import pillow_available
from armwarden.preview.scene import Scene, TextStamp, View
from armwarden.preview.sweep import draw_sweeps

if TYPE_CHECKING:  # pragma: no cover
    from armwarden.core.trajectory import JointTrajectory
    from armwarden.robot.model import RobotModel
    from armwarden.safety.limits import EnvelopeLimits, EnvelopeReport

#: configurations at which the swept links are drawn (evenly spaced in time, start and goal included)
SWEEP_SAMPLES = 8
#: at most this many points on the TCP polyline (waypoints are thinned evenly beyond that)
MAX_PATH_POINTS = 64
MIN_SIZE = (160, 96)
DEFAULT_SIZE = (640, 320)
#: static scenes kept per previewer (one per picture scale; plans inside the workspace share one),
#: about 5 MB each at the default size
MAX_SCENES = 4


class PlanPreviewer:
    """Renders the preview of plans checked against one policy's limits, at one size.

    Keeps the static scene of each picture scale it drew (at most `MAX_SCENES`), so a plan's
    picture costs its forward kinematics, its own strokes and the PNG encoding.
    """

    def __init__(self, limits: EnvelopeLimits, size: tuple[int, int] = DEFAULT_SIZE) -> None:
        width, height = int(size[0]), int(size[1])
        if width < MIN_SIZE[0] or height < MIN_SIZE[1]:
            raise ValueError(f"preview size must be at least {MIN_SIZE[0]}x{MIN_SIZE[1]} px, got {width}x{height}")
        self.limits = limits
        self.size = (width, height)
        self._scenes: dict[tuple[float, ...], Scene] = {}
        #: one picture at a time: a scene's pictures are all drawn on its one canvas
        self._drawing = threading.Lock()

    def render(
        self,
        robot: RobotModel,
        trajectory: JointTrajectory | None,
        report: EnvelopeReport,
        *,
        status: str | None = None,
    ) -> bytes | None:
        """PNG bytes of the plan preview, or None when Pillow is missing (a broken install).

        `status` defaults to what the report implies (hard violation → rejected, soft →
        needs_approval, none → ok); pass the Guard's own verdict when it knows more (e.g.
        planner findings that are not in the envelope report). A missing or malformed
        trajectory is drawn as the boxes alone.
        """
        if not pillow_available():
            return None
        if status is None:
            status = "rejected" if report.hard else ("needs_approval" if report.soft else "ok")
        geometry = _plan_geometry(robot, trajectory, report, self.limits)
        with self._drawing:
            return self._draw(geometry, trajectory, report, status)

    def _draw(self, geometry: _PlanGeometry | None, trajectory: JointTrajectory | None, report: EnvelopeReport,
              status: str) -> bytes:
        from PIL import ImageDraw

        scene = self._scene(*_bounds(self.limits, geometry))
        image = scene.start()
        draw = ImageDraw.Draw(image)  # every stroke drawn per plan is opaque: no blending needed

        # ---- title line
        duration = trajectory.duration_s if geometry is not None and trajectory is not None else 0.0
        n_hard, n_soft = len(report.hard), len(report.soft)
        title_y = 2
        scene.text(image, (6, title_y), status.upper(), palette.STATUS_COLOUR.get(status, palette.TEXT))
        x = 6 + scene.text_length(status.upper())
        # the words are the same in every title, the numbers are not: (text, is a number) runs
        runs = [("   duration ", False), (f"{duration:.2f}", True), (" s   TCP path ", False),
                (f"{report.tcp_path_length_m:.3f}", True), (" m", False)]
        if n_hard or n_soft:
            runs += [("   violations: ", False), (str(n_hard), True), (" hard, ", False), (str(n_soft), True), (" soft", False)]
        if not scene.line(image, x, title_y, runs, palette.TEXT):
            TextStamp(scene.font, "".join(text for text, _ in runs), (x, title_y)).paste(image, palette.TEXT)

        if geometry is not None:
            draw_sweeps(scene, geometry.capsules, geometry.radii)
            for view in scene.views:
                _draw_path(draw, view, geometry)
        return scene.encoder.encode(scene.canvas)

    def _scene(self, lo: np.ndarray, hi: np.ndarray) -> Scene:
        key = (*np.round(lo, 9).tolist(), *np.round(hi, 9).tolist())
        scene = self._scenes.get(key)
        if scene is None:
            if len(self._scenes) >= MAX_SCENES:
                self._scenes.pop(next(iter(self._scenes)))  # the oldest: plans far outside the box are rare
            scene = self._scenes[key] = Scene(self.size, lo, hi, self.limits)
        return scene


def render_plan_preview(
    robot: RobotModel,
    limits: EnvelopeLimits,
    trajectory: JointTrajectory | None,
    report: EnvelopeReport,
    *,
    size: tuple[int, int] = DEFAULT_SIZE,
    status: str | None = None,
) -> bytes | None:
    """One picture without a cached scene (see `PlanPreviewer.render`; the daemon keeps a
    `PlanPreviewer` per policy instead)."""
    return PlanPreviewer(limits, size).render(robot, trajectory, report, status=status)


# ---------------------------------------------------------------------------- geometry of the plan
class _PlanGeometry:
    __slots__ = ("capsules", "marks", "radii", "tcp_path")

    def __init__(self, tcp_path: np.ndarray, capsules: np.ndarray, radii: np.ndarray, marks: np.ndarray) -> None:
        self.tcp_path = tcp_path  # (P, 3)
        self.capsules = capsules  # (S, B, 2, 3): sample, capsule, end point
        self.radii = radii  # (B,)
        self.marks = marks  # (V, 3) violation positions


def _plan_geometry(robot: RobotModel, trajectory: JointTrajectory | None, report: EnvelopeReport,
                   limits: EnvelopeLimits | None = None) -> _PlanGeometry | None:
    """Every point the picture needs, from one batched forward-kinematics call; None if unusable.
    A keep-out violation is marked where its body meets the zone (`_contact_point`), so the mark
    lies inside the drawn zone in both views; other violations at the centre of their bodies."""
    if trajectory is None:
        return None
    positions = np.asarray(trajectory.positions)
    times = np.asarray(trajectory.times)
    if positions.ndim != 2 or len(positions) == 0 or positions.shape[1] != robot.nq or len(times) != len(positions):
        return None
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(times))):
        return None

    n_way = len(positions)
    path_index = np.unique(np.round(np.linspace(0, n_way - 1, min(n_way, MAX_PATH_POINTS))).astype(int))
    duration = trajectory.duration_s
    sweep_q = [trajectory.sample(t) for t in np.linspace(0.0, duration, SWEEP_SAMPLES)]
    timed = [(v, v.time_s) for v in report.violations if v.time_s is not None and math.isfinite(v.time_s)]
    mark_q = [trajectory.sample(time_s) for _, time_s in timed]

    tcp_path = robot.tcp_points(positions[path_index])  # the path needs the TCP only
    p0, p1 = robot.body_points(robot.joint_frames(np.vstack([*sweep_q, *mark_q])))  # (N, B+1, 3), the TCP last
    n_sweep = len(sweep_q)
    capsules = np.stack([p0[:n_sweep, :-1], p1[:n_sweep, :-1]], axis=2)

    centres = (p0[:, :-1] + p1[:, :-1]) / 2.0
    index = _body_index(robot) if timed else {}
    marks = []
    for k, (violation, _) in enumerate(timed):
        row = n_sweep + k
        bodies = [index.get(part) for part in (violation.body or "").split("|")]
        found = [b for b in bodies if b is not None]
        if violation.code.value == "KEEP_OUT" and limits is not None and limits.keep_out:
            ends = [(p0[row, b], p1[row, b]) for b in found] or [(p0[row, -1], p0[row, -1])]
            marks.append(_contact_point(ends, limits))
            continue
        marks.append(np.mean(centres[row, found], axis=0) if found else p0[row, -1])
    marks_arr = np.array(marks, dtype=float).reshape(-1, 3)
    return _PlanGeometry(tcp_path, capsules, np.asarray(robot.capsule_radii, dtype=float), marks_arr)


def _contact_point(segments: list[tuple[np.ndarray, np.ndarray]], limits: EnvelopeLimits) -> np.ndarray:
    """The point of a keep-out zone nearest to the violating bodies' axes (segments p0→p1): where
    the padded body reaches into the zone, and a point of the zone itself."""
    t = np.linspace(0.0, 1.0, 33)[:, None]
    points = np.vstack([a + t * (b - a) for a, b in segments])  # (N, 3) along every segment
    best, best_distance = points[0], math.inf
    for zone in limits.keep_out:
        lo, hi = np.asarray(zone.lo, dtype=float), np.asarray(zone.hi, dtype=float)
        inside = np.clip(points, lo, hi)  # each point's nearest point of the zone
        distances = np.linalg.norm(points - inside, axis=1)
        k = int(np.argmin(distances))
        if distances[k] < best_distance:
            best, best_distance = inside[k], float(distances[k])
    return best


def _body_index(robot: RobotModel) -> dict[str, int]:
    """Capsule index per body name, named as the envelope names them in violations."""
    per_link: dict[str, int] = {}
    for capsule in robot.capsules:
        per_link[capsule.link] = per_link.get(capsule.link, 0) + 1
    index: dict[str, int] = {}
    for i, capsule in enumerate(robot.capsules):
        index[capsule.link + (f"#{capsule.name}" if per_link[capsule.link] > 1 else "")] = i
        index.setdefault(capsule.link, i)
    return index


def _bounds(limits: EnvelopeLimits, geometry: _PlanGeometry | None) -> tuple[np.ndarray, np.ndarray]:
    lo = np.minimum(np.asarray(limits.workspace.lo, dtype=float), 0.0)
    hi = np.maximum(np.asarray(limits.workspace.hi, dtype=float), 0.0)
    for zone in limits.keep_out:
        lo, hi = np.minimum(lo, zone.lo), np.maximum(hi, zone.hi)
    if geometry is not None:
        r = float(np.max(geometry.radii)) if geometry.radii.size else 0.0
        pts = [geometry.tcp_path, geometry.marks, geometry.capsules.reshape(-1, 3)]
        allpts = np.vstack([p for p in pts if p.size])
        lo = np.minimum(lo, allpts.min(axis=0) - r)
        hi = np.maximum(hi, allpts.max(axis=0) + r)
    pad = 0.04 * float(np.max(hi - lo)) + 0.02
    lo, hi = lo - pad, hi + pad
    return lo, np.maximum(hi, lo + 1e-3)



def _draw_path(draw: Any, view: View, geometry: _PlanGeometry) -> None:
    """A panel's strokes over everything else: the TCP path, a red X at each violation, and the
    start and goal dots."""
    path = view.pts(geometry.tcp_path)
    if len(path) > 1:
        draw.line(path, fill=palette.PATH, width=2, joint="curve")
    for px, py in view.pts(geometry.marks):
        arm = 5
        draw.line([(px - arm, py - arm), (px + arm, py + arm)], fill=palette.VIOLATION, width=3)
        draw.line([(px - arm, py + arm), (px + arm, py - arm)], fill=palette.VIOLATION, width=3)
    for (px, py), colour in ((path[0], palette.START), (path[-1], palette.GOAL)):  # small enough to leave the X visible
        draw.ellipse((px - 3, py - 3, px + 3, py + 3), fill=colour)




__all__ = ["DEFAULT_SIZE", "PlanPreviewer", "render_plan_preview"]
