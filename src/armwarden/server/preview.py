"""The plan preview picture attached to every `PlanSummary`, for the human who approves the plan.

Two panels side by side, in the robot base frame: a TOP view (x right, y up) and a SIDE view
(x right, z up), both at the same scale. Each shows the workspace box, the keep-out zones
(semi-transparent red, named), the links swept along the plan (light grey capsules at a few
evenly spaced instants), the TCP path (green dot at the start, blue dot at the goal), the robot
base, and a red X wherever a violation with a time was found. The title line gives the status,
duration and TCP path length.

Cheap enough to stay on by default (issue 13: ≤ 3 ms p95 for a typical plan). `PlanPreviewer`
keeps, per policy, the static scene (frames, ticks, labels, scale bars) for each picture scale
it has drawn — every plan inside the workspace box has the same one — and per plan draws only
what changes: the title (its words and digits pasted from stamps rendered once), the sweep, the
zones over it, the path and the marks. The sweep's masks and outlines are computed in NumPy (one
capsule drawing pass, no per-sample image filters), the path needs forward kinematics for the
TCP alone, and the PNG is encoded without per-row filter search, compressing only the row bands
the plan drew on (`images.BandedPngEncoder`; the scene's own bands are compressed once). The
daemon's previewer also lets Pillow reuse freed image memory (`images.keep_freed_image_blocks`).

Pillow is optional (`armwarden[image]`); without it the renderer returns None. The output is
deterministic: the same inputs give the same bytes (Pillow's built-in default font, no
timestamps or other metadata in the PNG).

Not thread safe on its own: it runs forward kinematics on `robot`, whose Pinocchio data is
shared, and keeps its scene cache unlocked, so call it wherever the robot model is otherwise
used (the Guard's planning thread).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from armwarden.server.images import BandedPngEncoder

if TYPE_CHECKING:  # pragma: no cover
    from armwarden.planning.trajectory import JointTrajectory
    from armwarden.robot.model import RobotModel
    from armwarden.safety.envelope import EnvelopeLimits, EnvelopeReport

#: configurations at which the swept links are drawn (evenly spaced in time, start and goal included)
SWEEP_SAMPLES = 8
#: at most this many points on the TCP polyline (waypoints are thinned evenly beyond that)
MAX_PATH_POINTS = 64
MIN_SIZE = (160, 96)
DEFAULT_SIZE = (640, 320)
#: static scenes kept per previewer (one per picture scale; plans inside the workspace share one)
MAX_SCENES = 8

_WHITE = (255, 255, 255)
_FRAME = (165, 165, 165)
_TEXT = (40, 40, 40)
_WORKSPACE = (50, 80, 160)
_KEEP_OUT_FILL = (230, 70, 70, 70)
_KEEP_OUT_EDGE = (170, 50, 50)
_KEEP_OUT_TEXT = (130, 25, 25)
_LINK_FILL = (228, 228, 228)
_LINK_EDGE = (160, 160, 160)
_LINK_GOAL = (95, 95, 95)
_PATH = (235, 140, 0)
_START = (0, 165, 60)
_GOAL = (0, 80, 230)
_BASE = (30, 30, 30)
_VIOLATION = (255, 0, 0)  # the only saturated red in the picture
_STATUS_COLOUR = {"ok": (0, 125, 45), "needs_approval": (185, 115, 0), "rejected": (150, 0, 0)}
_SEPARATOR = (215, 215, 215)
#: palette of the swept links' pixels: unused, fill, outlines of the earlier poses, the goal pose's outline
_SWEEP_PALETTE = [0, 0, 0, *_LINK_FILL, *_LINK_EDGE, *_LINK_GOAL]

_NICE_STEPS = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0)


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
        self._scenes: dict[tuple[float, ...], _Scene] = {}

    def render(
        self,
        robot: RobotModel,
        trajectory: JointTrajectory | None,
        report: EnvelopeReport,
        *,
        status: str | None = None,
    ) -> bytes | None:
        """PNG bytes of the plan preview, or None when Pillow is not installed.

        `status` defaults to what the report implies (hard violation → rejected, soft →
        needs_approval, none → ok); pass the Guard's own verdict when it knows more (e.g.
        planner findings that are not in the envelope report). A missing or malformed
        trajectory is drawn as the boxes alone.
        """
        try:
            from PIL import ImageDraw
        except ImportError:
            return None
        if status is None:
            status = "rejected" if report.hard else ("needs_approval" if report.soft else "ok")

        geometry = _plan_geometry(robot, trajectory, report, self.limits)
        scene = self._scene(*_bounds(self.limits, geometry))
        image = scene.image.copy()
        draw = ImageDraw.Draw(image, "RGBA")  # RGBA drawing blends translucent fills onto the RGB image
        font = scene.font

        # ---- title line
        duration = trajectory.duration_s if geometry is not None and trajectory is not None else 0.0
        n_hard, n_soft = len(report.hard), len(report.soft)
        title_y = 2
        scene.text(image, (6, title_y), status.upper(), _STATUS_COLOUR.get(status, _TEXT))
        x = 6 + scene.text_length(status.upper())
        # the words are the same in every title, the numbers are not: (text, is a number) runs
        runs = [("   duration ", False), (f"{duration:.2f}", True), (" s   TCP path ", False),
                (f"{report.tcp_path_length_m:.3f}", True), (" m", False)]
        if n_hard or n_soft:
            runs += [("   violations: ", False), (str(n_hard), True), (" hard, ", False), (str(n_soft), True), (" soft", False)]
        if not scene.line(image, x, title_y, runs, _TEXT):
            draw.text((x, title_y), "".join(text for text, _ in runs), fill=_TEXT, font=font)

        for view in scene.views:
            _draw_plan(image, draw, scene, view, self.limits, geometry)
        return scene.encode(image, self.limits)

    def _scene(self, lo: np.ndarray, hi: np.ndarray) -> _Scene:
        key = (*np.round(lo, 9).tolist(), *np.round(hi, 9).tolist())
        scene = self._scenes.get(key)
        if scene is None:
            if len(self._scenes) >= MAX_SCENES:
                self._scenes.pop(next(iter(self._scenes)))  # the oldest: plans far outside the box are rare
            scene = self._scenes[key] = _Scene(self.size, lo, hi)
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
    index = _body_index(robot)
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


# ---------------------------------------------------------------------------- drawing
class _Scene:
    """What every plan drawn at one scale shares: the white picture with the panel frames, ticks,
    axis labels, panel names and scale bars already drawn, and each panel's `_View`."""

    def __init__(self, size: tuple[int, int], lo: np.ndarray, hi: np.ndarray) -> None:
        from PIL import Image, ImageDraw, ImageFont

        width, height = size
        self.font = font = ImageFont.load_default()
        self.image = image = Image.new("RGB", (width, height), _WHITE)
        draw = ImageDraw.Draw(image, "RGBA")
        text_h = _text_height(draw, font)
        top = 2 + text_h + 4  # below the title line

        # one scale for both panels, chosen so everything drawn fits
        panel_w = width // 2
        margin_l, margin_r = int(draw.textlength("-0.25", font=font)) + 6, 6
        margin_t, margin_b = text_h + 4, 2 * text_h + 8
        plot_w = panel_w - margin_l - margin_r
        plot_h = height - top - margin_t - margin_b
        span = hi - lo
        scale = min(plot_w / span[0], plot_h / span[1], plot_h / span[2])  # px per metre
        step = next((s for s in _NICE_STEPS if s * scale >= 4.5 * text_h), _NICE_STEPS[-1])

        self._stamps: dict[tuple[str, float, float], _TextStamp] = {}
        self._lengths: dict[str, float] = {}
        self.views: list[_View] = []
        for index, (axis_v, name) in enumerate(((1, "TOP (x-y)"), (2, "SIDE (x-z)"))):
            left = index * panel_w + margin_l
            box = (left, top + margin_t, left + plot_w, top + margin_t + plot_h)
            view = _View(box, scale, lo, hi, axis_v)
            _draw_frame(draw, font, text_h, view, name, "xyz"[axis_v], step)
            self.views.append(view)
            if index == 0:
                draw.line([(panel_w, top), (panel_w, height - 2)], fill=_SEPARATOR, width=1)
        self._encoder: BandedPngEncoder | None = None

    def encode(self, image: Any, limits: EnvelopeLimits) -> bytes:
        """PNG of a picture drawn on this scene: only the row bands that differ from the scene with
        its zones and base (and no plan) are compressed (`BandedPngEncoder`)."""
        if self._encoder is None:
            from PIL import ImageDraw

            reference = self.image.copy()
            draw = ImageDraw.Draw(reference, "RGBA")
            for view in self.views:
                _draw_plan(reference, draw, self, view, limits, None)
            self._encoder = BandedPngEncoder(reference)
        return self._encoder.encode(image)

    def text_length(self, text: str) -> float:
        """`ImageDraw.textlength` of `text` in the scene's font, measured once per text."""
        length = self._lengths.get(text)
        if length is None:
            length = self._lengths[text] = float(self.font.getlength(text))
        return length

    def line(self, image: Any, x: float, y: float, runs: list[tuple[str, bool]], fill: tuple[int, int, int]) -> bool:
        """Draw one line of text from stamps: each fixed run as one stamp, each variable run
        (a number) glyph by glyph, so that the stamps kept stay few (the runs of the titles and
        one per character). Exact only where every glyph lands on a whole pixel, as in the
        default font (whole-pixel advances, no kerning): the line is then the same as
        `ImageDraw.text` draws it. Returns False, drawing nothing, where that does not hold."""
        pieces: list[tuple[str, float]] = []
        for text, variable in runs:
            for piece in (text if variable else (text,)):
                pieces.append((piece, x))
                x += self.text_length(piece)
        if not all(float(at).is_integer() for _, at in pieces) or not float(y).is_integer():
            return False
        for piece, at in pieces:
            if piece.strip():
                self.text(image, (0.0, y), piece, fill, shift=int(at))
        return True

    def text(self, image: Any, xy: tuple[float, float], text: str, fill: tuple[int, int, int], shift: int = 0) -> None:
        """`ImageDraw.text` for text every picture of this scene repeats (zone names, the status
        word, the title's words and digits): rendered by FreeType once at `xy`, then pasted there,
        or `shift` whole pixels to the right (the same glyphs, since the fraction is unchanged)."""
        key = (text, *xy)
        stamp = self._stamps.get(key)
        if stamp is None:
            stamp = self._stamps[key] = _TextStamp(self.font, text, xy)
        stamp.paste(image, fill, shift)


class _TextStamp:
    """One line of text at one position, rendered once as a coverage mask (what `ImageDraw.text`
    blends the ink with), so that drawing it again is one masked paste."""

    PAD = 4

    def __init__(self, font: Any, text: str, xy: tuple[float, float]) -> None:
        from PIL import Image, ImageDraw

        x, y = xy
        left, top, right, bottom = font.getbbox(text)
        width = math.ceil(max(right, 0) - min(left, 0)) + 2 * self.PAD + 2
        height = math.ceil(max(bottom, 0) - min(top, 0)) + 2 * self.PAD + 2
        self.mask = Image.new("L", (width, height), 0)
        # same integer/fraction split as ImageDraw.text, so the glyphs land on the same pixels
        shift_x, shift_y = self.PAD - min(math.floor(left), 0), self.PAD - min(math.floor(top), 0)
        ImageDraw.Draw(self.mask).text((x - int(x) + shift_x, y - int(y) + shift_y), text, fill=255, font=font)
        self.origin = (int(x) - shift_x, int(y) - shift_y)

    def paste(self, image: Any, fill: tuple[int, int, int], shift: int = 0) -> None:
        image.paste(fill, (self.origin[0] + shift, self.origin[1]), mask=self.mask)


class _View:
    """Maps base-frame points to pixels in one panel: x to the right, `axis_v` (y or z) up."""

    def __init__(self, box: tuple[int, int, int, int], scale: float, lo: np.ndarray, hi: np.ndarray, axis_v: int) -> None:
        self.box = box
        self.scale = scale
        self.axis_v = axis_v
        self.cu = (lo[0] + hi[0]) / 2.0
        self.cv = (lo[axis_v] + hi[axis_v]) / 2.0
        self.ox = (box[0] + box[2]) / 2.0
        self.oy = (box[1] + box[3]) / 2.0

    def px(self, u: float, v: float) -> tuple[float, float]:
        return (self.ox + (u - self.cu) * self.scale, self.oy - (v - self.cv) * self.scale)

    def coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel x and y (rounded to 0.01 px) of base-frame points (..., 3), flattened."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        x = self.ox + (points[:, 0] - self.cu) * self.scale
        y = self.oy - (points[:, self.axis_v] - self.cv) * self.scale
        return np.round(x, 2), np.round(y, 2)

    def pts(self, points: np.ndarray) -> list[tuple[float, float]]:
        x, y = self.coordinates(points)
        return list(zip(x.tolist(), y.tolist(), strict=True))

    def rect(self, lo: np.ndarray, hi: np.ndarray) -> tuple[float, float, float, float]:
        x0, y1 = self.px(lo[0], lo[self.axis_v])
        x1, y0 = self.px(hi[0], hi[self.axis_v])
        return (round(x0, 2), round(y0, 2), round(x1, 2), round(y1, 2))

    def u_range(self) -> tuple[float, float]:
        return (self.cu - (self.ox - self.box[0]) / self.scale, self.cu + (self.box[2] - self.ox) / self.scale)

    def v_range(self) -> tuple[float, float]:
        return (self.cv - (self.box[3] - self.oy) / self.scale, self.cv + (self.oy - self.box[1]) / self.scale)


def _draw_frame(draw: Any, font: Any, text_h: int, view: _View, name: str, v_name: str, step: float) -> None:
    """A panel's static parts: name, axis labels, frame, ticks and the scale bar (below the plot)."""
    x0, y0, x1, y1 = view.box
    # panel name, centred above the plot; the vertical axis label above the vertical axis
    draw.text(((x0 + x1 - draw.textlength(name, font=font)) / 2, y0 - text_h - 3), name, fill=_TEXT, font=font)
    draw.text((x0 + 2, y0 - text_h - 3), f"{v_name} [m]", fill=_TEXT, font=font)
    draw.rectangle(view.box, outline=_FRAME, width=1)
    _draw_ticks(draw, font, text_h, view, step)

    # scale bar, right-aligned on the axis-label line below the plot
    bar = step * view.scale
    sx1, sy = x1 - 2, y1 + text_h + 6 + text_h / 2
    draw.line([(sx1 - bar, sy), (sx1, sy)], fill=_TEXT, width=2)
    for sx in (sx1 - bar, sx1):
        draw.line([(sx, sy - 3), (sx, sy + 3)], fill=_TEXT, width=1)
    label = f"{_fmt_m(step)} m"
    draw.text((sx1 - bar - 4 - draw.textlength(label, font=font), sy - text_h / 2 - 1), label, fill=_TEXT, font=font)


def _draw_plan(image: Any, draw: Any, scene: _Scene, view: _View, limits: EnvelopeLimits,
               geometry: _PlanGeometry | None) -> None:
    """A panel's plan-dependent parts, in z-order: the sweep, the zones over it, the base, the path."""
    # swept links first, so the translucent zones and the workspace outline stay visible over them
    if geometry is not None:
        _draw_sweep(image, view, geometry)
    draw.rectangle(view.rect(limits.workspace.lo, limits.workspace.hi), outline=_WORKSPACE, width=2)
    for zone in limits.keep_out:
        rect = view.rect(zone.lo, zone.hi)
        draw.rectangle(rect, fill=_KEEP_OUT_FILL, outline=_KEEP_OUT_EDGE, width=1)
    for zone in limits.keep_out:  # names on top of every fill, so overlapping zones stay legible
        rect = view.rect(zone.lo, zone.hi)
        scene.text(image, (rect[0] + 2, rect[1] + 1), zone.name, _KEEP_OUT_TEXT)

    # robot base at the origin, over the links
    bx, by = view.px(0.0, 0.0)
    draw.rectangle((bx - 5, by - 5, bx + 5, by + 5), fill=_BASE)
    if geometry is None:
        return
    path = view.pts(geometry.tcp_path)
    if len(path) > 1:
        draw.line(path, fill=_PATH, width=2, joint="curve")
    for px, py in view.pts(geometry.marks):
        arm = 5
        draw.line([(px - arm, py - arm), (px + arm, py + arm)], fill=_VIOLATION, width=3)
        draw.line([(px - arm, py + arm), (px + arm, py - arm)], fill=_VIOLATION, width=3)
    for (px, py), colour in ((path[0], _START), (path[-1], _GOAL)):  # small enough to leave the X visible
        draw.ellipse((px - 3, py - 3, px + 3, py + 3), fill=colour)


def _draw_sweep(image: Any, view: _View, geometry: _PlanGeometry) -> None:
    """Swept links: the union of all sampled capsules filled light grey, each sample outlined.

    Every capsule is a thick line with round caps (width ∝ radius) drawn into its sample's mask,
    so overlapping capsules do not darken each other; the outline of each sampled pose is its
    mask's edge (mask pixels with a background pixel among their 8 neighbours), darker for the
    goal pose. All samples are drawn into one tall mask, one band per sample, and the union and
    outlines are computed on the bands at once.
    """
    from PIL import Image, ImageDraw

    radii = geometry.radii.tolist()
    r_max = max(1.0, max(radii, default=0.0) * view.scale)
    if not geometry.capsules.size:
        return
    n_samples = len(geometry.capsules)
    xs, ys = view.coordinates(geometry.capsules)  # every sample's end points in one pass
    # work only on the pixels the sweep can cover (within the plot)
    x0 = max(view.box[0], math.floor(float(xs.min()) - r_max) - 2)
    y0 = max(view.box[1], math.floor(float(ys.min()) - r_max) - 2)
    x1 = min(view.box[2], math.ceil(float(xs.max()) + r_max) + 2)
    y1 = min(view.box[3], math.ceil(float(ys.max()) + r_max) + 2)
    if x1 <= x0 or y1 <= y0:
        return
    w, h = x1 - x0 + 1, y1 - y0 + 1
    gap = 2 * math.ceil(r_max) + 4  # strokes cut at the region's edge spill into the gap, not the next band
    stride = h + gap
    tall = Image.new("L", (w, stride * n_samples), 0)
    # Pillow's drawing primitives, without `ImageDraw`'s per-call colour parsing (hundreds of
    # strokes per picture, all of one ink): the same calls `ImageDraw.line`/`ellipse` make
    pen = ImageDraw.Draw(tall).draw
    r_pxs = [float(max(1.0, radius * view.scale)) for radius in radii]  # Python floats: round() gives an int
    widths = [max(1, round(2 * r_px)) for r_px in r_pxs]
    # every stroke's arguments in one pass: (S, B, 2 ends, 2) end points in the tall mask, and
    # each end's round cap as a bounding box; all strokes are one ink, so their order is free
    ends = np.stack([xs.reshape(n_samples, -1) - x0,
                     ys.reshape(n_samples, -1) + (np.arange(n_samples) * stride - y0)[:, None]], axis=-1)
    ends = ends.reshape(n_samples, len(r_pxs), 2, 2)
    r_ends = np.array(r_pxs)[None, :, None, None]
    caps = np.concatenate([ends - r_ends, ends + r_ends], axis=-1).reshape(-1, 4).tolist()
    for sample in ends.tolist():
        for stroke, width in zip(sample, widths, strict=True):
            pen.draw_lines(stroke, 255, width)
    for cap in caps:
        pen.draw_ellipse(cap, 255, 1)
    bands: np.ndarray = np.frombuffer(tall.tobytes(), dtype=np.uint8).reshape(n_samples, stride, w)[:, :h] > 0
    outlines: np.ndarray = bands & ~_interior(bands)  # (S, h, w)
    # one palette index per pixel (0 untouched, then fill, earlier outlines, the goal's outline),
    # coloured by Pillow and pasted through the union as mask: one C pass, no per-colour NumPy masking
    union = np.any(bands, axis=0).view(np.uint8)
    index = np.maximum(union, np.any(outlines[:-1], axis=0).view(np.uint8) * np.uint8(2))
    index = np.maximum(index, outlines[-1].view(np.uint8) * np.uint8(3))
    colours = Image.frombytes("P", (w, h), index.tobytes())
    colours.putpalette(_SWEEP_PALETTE)
    image.paste(colours.convert("RGB"), (x0, y0), Image.frombytes("L", (w, h), (union * np.uint8(255)).tobytes()))


def _interior(masks: np.ndarray) -> np.ndarray:
    """Pixels of (S, h, w) boolean masks whose 8 neighbours are all set (outside the image counts
    as unset, so a set pixel on the border is an outline pixel, as Pillow's FIND_EDGES leaves it).
    The 3×3 neighbourhood is a row of three then a column of three: four ANDs, not eight."""
    across = np.zeros_like(masks)
    across[:, :, 1:-1] = masks[:, :, :-2] & masks[:, :, 1:-1] & masks[:, :, 2:]
    inner = np.zeros_like(masks)
    inner[:, 1:-1, :] = across[:, :-2, :] & across[:, 1:-1, :] & across[:, 2:, :]
    return inner


def _draw_ticks(draw: Any, font: Any, text_h: int, view: _View, step: float) -> None:
    x0, _, x1, y1 = view.box
    u_lo, u_hi = view.u_range()
    for k in range(math.ceil(u_lo / step), math.floor(u_hi / step) + 1):
        px, _ = view.px(k * step, 0.0)
        draw.line([(px, y1), (px, y1 + 3)], fill=_FRAME, width=1)
        label = _fmt_m(k * step)
        draw.text((px - draw.textlength(label, font=font) / 2, y1 + 4), label, fill=_TEXT, font=font)
    axis = "x [m]"
    draw.text(((x0 + x1 - draw.textlength(axis, font=font)) / 2, y1 + text_h + 6), axis, fill=_TEXT, font=font)
    v_lo, v_hi = view.v_range()
    for k in range(math.ceil(v_lo / step), math.floor(v_hi / step) + 1):
        _, py = view.px(0.0, k * step)
        draw.line([(x0 - 3, py), (x0, py)], fill=_FRAME, width=1)
        label = _fmt_m(k * step)
        draw.text((x0 - 4 - draw.textlength(label, font=font), py - text_h / 2 - 1), label, fill=_TEXT, font=font)


def _fmt_m(value: float) -> str:
    text = f"{value:.2f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _text_height(draw: Any, font: Any) -> int:
    box = draw.textbbox((0, 0), "Hg[0.5]", font=font)
    return int(box[3] - min(box[1], 0))


__all__ = ["DEFAULT_SIZE", "PlanPreviewer", "render_plan_preview"]
