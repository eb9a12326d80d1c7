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

Threads: a previewer draws one picture at a time (every picture of a scene is drawn on that
scene's one canvas, under a lock), but it runs forward kinematics on the `robot` it is given,
whose Pinocchio data is not thread safe: call it wherever that robot model is otherwise used
(the Guard's planning thread).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from armwarden.preview.images import BandedPngEncoder, mask_image, pillow_available, rgbx_image, rgbx_words

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
#: the swept links' colours, by their index in the sweep's masks (0 is a pixel the sweep left alone):
#: fill, outlines of the earlier poses, the goal pose's outline
_SWEEP_COLOURS = (_LINK_FILL, _LINK_EDGE, _LINK_GOAL)

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
        scene.text(image, (6, title_y), status.upper(), _STATUS_COLOUR.get(status, _TEXT))
        x = 6 + scene.text_length(status.upper())
        # the words are the same in every title, the numbers are not: (text, is a number) runs
        runs = [("   duration ", False), (f"{duration:.2f}", True), (" s   TCP path ", False),
                (f"{report.tcp_path_length_m:.3f}", True), (" m", False)]
        if n_hard or n_soft:
            runs += [("   violations: ", False), (str(n_hard), True), (" hard, ", False), (str(n_soft), True), (" soft", False)]
        if not scene.line(image, x, title_y, runs, _TEXT):
            _TextStamp(scene.font, "".join(text for text, _ in runs), (x, title_y)).paste(image, _TEXT)

        if geometry is not None:
            _draw_sweeps(scene, geometry)
            for view in scene.views:
                _draw_path(draw, view, geometry)
        return scene.encoder.encode(scene.canvas)

    def _scene(self, lo: np.ndarray, hi: np.ndarray) -> _Scene:
        key = (*np.round(lo, 9).tolist(), *np.round(hi, 9).tolist())
        scene = self._scenes.get(key)
        if scene is None:
            if len(self._scenes) >= MAX_SCENES:
                self._scenes.pop(next(iter(self._scenes)))  # the oldest: plans far outside the box are rare
            scene = self._scenes[key] = _Scene(self.size, lo, hi, self.limits)
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


# ---------------------------------------------------------------------------- drawing
class _Scene:
    """What every plan drawn at one scale shares: each panel's `_View`; the picture with the panel
    frames, ticks, axis labels, panel names and scale bars, the zones and the base, and no plan
    (`plain`, the encoder's reference); per panel, the layers the sweep's pixels are chosen from
    (`under`); and the canvas every picture is drawn on.

    The zones, their names, the workspace outline and the base are drawn over the sweep, and each
    of them changes a pixel by a function of that pixel alone (an opaque stroke, a translucent
    fill, a text mask's blend). So a swept pixel of a given colour ends up as it does in a copy of
    the picture whose plot boxes were painted that colour before those overlays were drawn: the
    layers hold these copies, cut to each panel's box, and the sweep picks from them."""

    def __init__(self, size: tuple[int, int], lo: np.ndarray, hi: np.ndarray, limits: EnvelopeLimits) -> None:
        from PIL import Image, ImageDraw, ImageFont

        width, height = size
        self.font = font = ImageFont.load_default()
        image = Image.new("RGB", (width, height), _WHITE)
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

        layers = [rgbx_words(self._overlaid(image, limits, None))]
        layers += [rgbx_words(self._overlaid(image, limits, colour)) for colour in _SWEEP_COLOURS]
        self.under = [_SweepLayers(layers, view.box) for view in self.views]
        self.encoder = BandedPngEncoder(layers[0])
        self.plain = self.encoder.reference  # read-only, the encoder's own copy
        self.canvas = self.plain.copy()
        self._picture = rgbx_image(self.canvas)

    def start(self) -> Any:
        """The canvas reset to the plain picture, as a Pillow image drawing into it. One picture at
        a time: the next call resets the same memory (the PNG is encoded before that)."""
        np.copyto(self.canvas, self.plain)
        return self._picture

    def _overlaid(self, static: Any, limits: EnvelopeLimits, sweep_colour: tuple[int, int, int] | None) -> Any:
        """The static picture with every plot box painted `sweep_colour` (None: left as is), then
        the zones, their names, the workspace outline and the base drawn over it."""
        from PIL import ImageDraw

        image = static.copy()
        draw = ImageDraw.Draw(image, "RGBA")  # RGBA drawing blends translucent fills onto the RGB image
        for view in self.views:
            if sweep_colour is not None:
                image.paste(sweep_colour, (view.box[0], view.box[1], view.box[2] + 1, view.box[3] + 1))
            _draw_overlay(image, draw, self, view, limits)
        return image

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


class _SweepLayers:
    """One panel's box in each of the scene's layers (the plain picture, then each sweep colour's),
    from which `paint` takes every pixel of a sweep: a gather by flat index, one pass."""

    def __init__(self, layers: list[np.ndarray], box: tuple[int, int, int, int]) -> None:
        x0, y0, x1, y1 = box
        self.origin = (x0, y0)
        self._width = x1 - x0 + 1
        self._plane = (y1 - y0 + 1) * self._width
        self._pixels = np.stack([layer[y0:y1 + 1, x0:x1 + 1] for layer in layers]).reshape(-1)

    def paint(self, canvas: np.ndarray, index: np.ndarray, x0: int, y0: int) -> None:
        """Set the canvas's (h, w) pixels from (`x0`, `y0`), inside the box, to the layer `index`
        names for each (0: the plain picture)."""
        h, w = index.shape
        left, top = x0 - self.origin[0], y0 - self.origin[1]
        rows = np.arange(top, top + h, dtype=np.intp)[:, None] * self._width
        flat = index.astype(np.intp) * self._plane + rows + np.arange(left, left + w, dtype=np.intp)
        canvas[y0:y0 + h, x0:x0 + w] = self._pixels[flat]


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
        inked = self.mask.getbbox()  # only the inked pixels are pasted: None when nothing is
        self._paste_area = None if inked is None else (inked, self.mask.crop(inked).im)

    def paste(self, image: Any, fill: tuple[int, int, int], shift: int = 0) -> None:
        """`Image.paste(fill, …, mask=self.mask)`, made on the image's core directly (the stamps
        are pasted some twenty times per picture, and `Image.paste` checks its arguments anew each
        time), and only over the inked part of the mask; the core clips the box to the image."""
        if self._paste_area is None:
            return
        (left, top, right, bottom), mask = self._paste_area
        x, y = self.origin[0] + shift + left, self.origin[1] + top
        image.im.paste(fill, (x, y, x + right - left, y + bottom - top), mask)


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


def _draw_overlay(image: Any, draw: Any, scene: _Scene, view: _View, limits: EnvelopeLimits) -> None:
    """What a panel draws over the swept links, the same for every plan: the workspace outline,
    the zones (translucent, so the links stay visible under them), their names and the base."""
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


def _draw_path(draw: Any, view: _View, geometry: _PlanGeometry) -> None:
    """A panel's strokes over everything else: the TCP path, a red X at each violation, and the
    start and goal dots."""
    path = view.pts(geometry.tcp_path)
    if len(path) > 1:
        draw.line(path, fill=_PATH, width=2, joint="curve")
    for px, py in view.pts(geometry.marks):
        arm = 5
        draw.line([(px - arm, py - arm), (px + arm, py + arm)], fill=_VIOLATION, width=3)
        draw.line([(px - arm, py + arm), (px + arm, py - arm)], fill=_VIOLATION, width=3)
    for (px, py), colour in ((path[0], _START), (path[-1], _GOAL)):  # small enough to leave the X visible
        draw.ellipse((px - 3, py - 3, px + 3, py + 3), fill=colour)


def _draw_sweeps(scene: _Scene, geometry: _PlanGeometry) -> None:
    """Swept links in every panel: the union of all sampled capsules filled light grey, each
    sample outlined.

    Every capsule is a thick line with round caps (width ∝ radius) drawn into its sample's mask,
    so overlapping capsules do not darken each other; the outline of each sampled pose is its
    mask's edge (mask pixels with a background pixel among their 8 neighbours; the edge of the
    region a panel's sweep can cover counts as background), darker for the goal pose.

    Both panels' samples are drawn into one tall mask, one band per panel and sample; the bands
    are then packed into one bit per sample in each pixel's byte(s), so the union and every
    sample's outline are computed at once, on an eighth of the bytes. Each pixel of the canvas
    is then taken from the panel's layer (`_Scene.under`) of its colour: the zones and the base
    over it come with it.
    """
    from PIL import ImageDraw

    if not geometry.capsules.size:
        return
    radii = geometry.radii.tolist()
    n_samples = len(geometry.capsules)
    scale = scene.views[0].scale  # one scale for every panel
    r_max = max(1.0, max(radii, default=0.0) * scale)
    regions: list[_SweepRegion] = []
    for view, under in zip(scene.views, scene.under, strict=True):
        xs, ys = view.coordinates(geometry.capsules)  # every sample's end points in one pass
        # work only on the pixels the sweep can cover (within the plot)
        x0 = max(view.box[0], math.floor(float(xs.min()) - r_max) - 2)
        y0 = max(view.box[1], math.floor(float(ys.min()) - r_max) - 2)
        x1 = min(view.box[2], math.ceil(float(xs.max()) + r_max) + 2)
        y1 = min(view.box[3], math.ceil(float(ys.max()) + r_max) + 2)
        if x1 > x0 and y1 > y0:
            regions.append(_SweepRegion(under, xs - x0, ys - y0, x0, y0, x1 - x0 + 1, y1 - y0 + 1))
    if not regions:
        return
    w, h = max(region.width for region in regions), max(region.height for region in regions)
    gap = 2 * math.ceil(r_max) + 4  # strokes cut at a region's edge spill into the gap, not the next band
    stride = h + gap
    n_bands = n_samples * len(regions)
    tall = np.zeros((stride * n_bands, w), dtype=np.uint8)
    # Pillow's drawing primitives on the array's memory, without `ImageDraw`'s per-call colour
    # parsing (hundreds of strokes per picture, all of one ink): the calls `ImageDraw.line` and
    # `ImageDraw.ellipse` make
    pen = ImageDraw.Draw(mask_image(tall)).draw
    r_pxs = [float(max(1.0, radius * scale)) for radius in radii]  # Python floats: round() gives an int
    widths = [max(1, round(2 * r_px)) for r_px in r_pxs]
    # every stroke's arguments in one pass: (panel·S, B, 2 ends, 2) end points in the tall mask,
    # and each end's round cap as a bounding box; all strokes are one ink, so their order is free
    xs = np.concatenate([region.xs for region in regions]).reshape(n_bands, -1)
    ys = np.concatenate([region.ys for region in regions]).reshape(n_bands, -1) + (np.arange(n_bands) * stride)[:, None]
    ends = np.stack([xs, ys], axis=-1).reshape(n_bands, len(r_pxs), 2, 2)
    r_ends = np.array(r_pxs)[None, :, None, None]
    caps = np.concatenate([ends - r_ends, ends + r_ends], axis=-1).reshape(-1, 4).tolist()
    draw_lines, draw_ellipse = pen.draw_lines, pen.draw_ellipse
    for stroke, width in zip(ends.reshape(-1, 4).tolist(), widths * n_bands, strict=True):  # flat x0, y0, x1, y1
        draw_lines(stroke, 255, width)
    for cap in caps:
        draw_ellipse(cap, 255, 1)

    # bit s % 8 of byte s // 8 of each pixel: whether sample s covers it (the mask's 255 masked
    # down to that bit; a loop of byte-wide ORs is far cheaper than `np.packbits` across bands)
    n_bytes = -(-n_samples // 8)
    bands = tall.reshape(n_bands, stride, w)
    samples = np.zeros((len(regions), n_bytes, h, w), dtype=np.uint8)
    for panel, region in enumerate(regions):
        rows, columns = slice(0, region.height), slice(0, region.width)
        packed = samples[panel, :, rows, columns]  # outside the region stays clear: its edge is background
        for sample in range(n_samples):
            packed[sample // 8] |= bands[panel * n_samples + sample, rows, columns] & np.uint8(1 << (sample % 8))
    outlines = samples & ~_interior(samples.reshape(-1, h, w)).reshape(samples.shape)
    goal_byte, goal_bit = divmod(n_samples - 1, 8)
    goal = outlines[:, goal_byte] & np.uint8(1 << goal_bit)
    outlines[:, goal_byte] &= np.uint8(~(1 << goal_bit) & 0xFF)  # the earlier samples' outlines
    # one colour index per pixel (0 untouched, then fill, earlier outlines, the goal's outline)
    index = np.any(samples, axis=1).view(np.uint8)
    index = np.maximum(index, np.any(outlines, axis=1).view(np.uint8) * np.uint8(2))
    index = np.maximum(index, (goal != 0).view(np.uint8) * np.uint8(3))
    for panel, region in enumerate(regions):
        region.under.paint(scene.canvas, index[panel, :region.height, :region.width], region.x0, region.y0)


@dataclass(frozen=True)
class _SweepRegion:
    """The part of one panel a sweep can cover: its layers, its end points in the region's own
    pixels (flattened, as `_View.coordinates` gives them), and where the region lies in the picture."""

    under: _SweepLayers
    xs: np.ndarray
    ys: np.ndarray
    x0: int
    y0: int
    width: int
    height: int


def _interior(masks: np.ndarray) -> np.ndarray:
    """Pixels of (K, h, w) masks whose 8 neighbours are all set (outside the image counts as unset,
    so a set pixel on the border is an outline pixel, as Pillow's FIND_EDGES leaves it). Bitwise:
    booleans, or bytes holding one mask per bit. The 3×3 neighbourhood is a row of three then a
    column of three: four ANDs, not eight."""
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
