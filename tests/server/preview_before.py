"""REFERENCE ONLY: the plan preview renderer as it was before issue 13 made it cheap (commit
02432ca, `src/armwarden/preview/render.py`), kept verbatim so `test_preview_reference.py` can
show that the optimised renderer draws the same picture. Not used by the daemon. One change
since: keep-out marks are placed where the body meets the zone (`preview._contact_point`, issue
14's picture-correctness fix), exactly as the renderer under test places them.

The plan preview picture attached to every `PlanSummary`, for the human who approves the plan.

Two panels side by side, in the robot base frame: a TOP view (x right, y up) and a SIDE view
(x right, z up), both at the same scale. Each shows the workspace box, the keep-out zones
(semi-transparent red, named), the links swept along the plan (light grey capsules at a few
evenly spaced instants), the TCP path (green dot at the start, blue dot at the goal), the robot
base, and a red X wherever a violation with a time was found. The title line gives the status,
duration and TCP path length.

Pillow is optional (`armwarden[image]`); without it `render_plan_preview` returns None. The
output is deterministic: the same inputs give the same bytes (Pillow's built-in default font,
no timestamps or other metadata in the PNG).

Not thread safe on its own: it runs forward kinematics on `robot`, whose Pinocchio data is
shared, so call it wherever the robot model is otherwise used (the Guard's planning thread).
"""

from __future__ import annotations

import io
import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from armwarden.core.trajectory import JointTrajectory
    from armwarden.robot.model import RobotModel
    from armwarden.safety.limits import EnvelopeLimits, EnvelopeReport

#: configurations at which the swept links are drawn (evenly spaced in time, start and goal included)
SWEEP_SAMPLES = 8
#: at most this many points on the TCP polyline (waypoints are thinned evenly beyond that)
MAX_PATH_POINTS = 200
MIN_SIZE = (160, 96)

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

_NICE_STEPS = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0)


def render_plan_preview(
    robot: RobotModel,
    limits: EnvelopeLimits,
    trajectory: JointTrajectory | None,
    report: EnvelopeReport,
    *,
    size: tuple[int, int] = (640, 320),
    status: str | None = None,
) -> bytes | None:
    """PNG bytes of the plan preview, or None when Pillow is not installed.

    `status` defaults to what the report implies (hard violation → rejected, soft →
    needs_approval, none → ok); pass the Guard's own verdict when it knows more (e.g. planner
    findings that are not in the envelope report). A missing or malformed trajectory is drawn
    as the boxes alone.
    """
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError:
        return None

    width, height = int(size[0]), int(size[1])
    if width < MIN_SIZE[0] or height < MIN_SIZE[1]:
        raise ValueError(f"preview size must be at least {MIN_SIZE[0]}x{MIN_SIZE[1]} px, got {width}x{height}")
    if status is None:
        status = "rejected" if report.hard else ("needs_approval" if report.soft else "ok")

    geometry = _plan_geometry(robot, trajectory, report, limits)
    font = ImageFont.load_default()
    image = Image.new("RGB", (width, height), _WHITE)
    draw = ImageDraw.Draw(image, "RGBA")  # RGBA drawing blends translucent fills onto the RGB image
    text_h = _text_height(draw, font)

    # ---- title line
    duration = trajectory.duration_s if geometry is not None and trajectory is not None else 0.0
    n_hard, n_soft = len(report.hard), len(report.soft)
    title_y = 2
    draw.text((6, title_y), status.upper(), fill=_STATUS_COLOUR.get(status, _TEXT), font=font)
    x = 6 + draw.textlength(status.upper(), font=font)
    details = f"   duration {duration:.2f} s   TCP path {report.tcp_path_length_m:.3f} m"
    if n_hard or n_soft:
        details += f"   violations: {n_hard} hard, {n_soft} soft"
    draw.text((x, title_y), details, fill=_TEXT, font=font)
    top = title_y + text_h + 4

    # ---- one scale for both panels, chosen so everything drawn fits
    lo, hi = _bounds(limits, geometry)
    panel_w = width // 2
    margin_l, margin_r = int(draw.textlength("-0.25", font=font)) + 6, 6
    margin_t, margin_b = text_h + 4, 2 * text_h + 8
    plot_w = panel_w - margin_l - margin_r
    plot_h = height - top - margin_t - margin_b
    span = hi - lo
    scale = min(plot_w / span[0], plot_h / span[1], plot_h / span[2])  # px per metre
    step = next((s for s in _NICE_STEPS if s * scale >= 4.5 * text_h), _NICE_STEPS[-1])

    for index, (axis_v, name) in enumerate(((1, "TOP (x-y)"), (2, "SIDE (x-z)"))):
        left = index * panel_w + margin_l
        box = (left, top + margin_t, left + plot_w, top + margin_t + plot_h)
        view = _View(box, scale, lo, hi, axis_v)
        _draw_panel(image, draw, font, text_h, view, name, "xyz"[axis_v], limits, geometry, step)
        if index == 0:
            draw.line([(panel_w, top), (panel_w, height - 2)], fill=(215, 215, 215), width=1)

    out = io.BytesIO()
    image.save(out, format="PNG", compress_level=1)  # encoding dominates the cost; size matters less
    return out.getvalue()


# ---------------------------------------------------------------------------- geometry of the plan
class _PlanGeometry:
    __slots__ = ("capsules", "marks", "radii", "tcp_path")

    def __init__(self, tcp_path: np.ndarray, capsules: np.ndarray, radii: np.ndarray, marks: np.ndarray) -> None:
        self.tcp_path = tcp_path  # (P, 3)
        self.capsules = capsules  # (S, B, 2, 3): sample, capsule, end point
        self.radii = radii  # (B,)
        self.marks = marks  # (V, 3) violation positions


def _plan_geometry(robot: RobotModel, trajectory: JointTrajectory | None, report: EnvelopeReport,
                   limits: EnvelopeLimits) -> _PlanGeometry | None:
    """Every point the picture needs, from one batched forward-kinematics call; None if unusable."""
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

    qs = np.vstack([positions[path_index], *sweep_q, *mark_q]) if mark_q else np.vstack([positions[path_index], *sweep_q])
    p0, p1 = robot.body_points(robot.joint_frames(qs))  # (N, B+1, 3), the TCP last
    n_path, n_sweep = len(path_index), len(sweep_q)
    tcp_path = p0[:n_path, -1]
    sweep = slice(n_path, n_path + n_sweep)
    capsules = np.stack([p0[sweep, :-1], p1[sweep, :-1]], axis=2)

    centres = (p0[:, :-1] + p1[:, :-1]) / 2.0
    index = _body_index(robot)
    marks = []
    for k, (violation, _) in enumerate(timed):
        row = n_path + n_sweep + k
        bodies = [index.get(part) for part in (violation.body or "").split("|")]
        found = [b for b in bodies if b is not None]
        if violation.code.value == "KEEP_OUT" and limits.keep_out:
            from armwarden.preview.render import _contact_point

            marks.append(_contact_point([(p0[row, b], p1[row, b]) for b in found] or [(p0[row, -1], p0[row, -1])], limits))
            continue
        marks.append(np.mean(centres[row, found], axis=0) if found else p0[row, -1])
    marks_arr = np.array(marks, dtype=float).reshape(-1, 3)
    return _PlanGeometry(tcp_path, capsules, np.asarray(robot.capsule_radii, dtype=float), marks_arr)


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

    def pts(self, points: np.ndarray) -> list[tuple[float, float]]:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        x = self.ox + (points[:, 0] - self.cu) * self.scale
        y = self.oy - (points[:, self.axis_v] - self.cv) * self.scale
        return list(zip(np.round(x, 2).tolist(), np.round(y, 2).tolist(), strict=True))

    def rect(self, lo: np.ndarray, hi: np.ndarray) -> tuple[float, float, float, float]:
        x0, y1 = self.px(lo[0], lo[self.axis_v])
        x1, y0 = self.px(hi[0], hi[self.axis_v])
        return (round(x0, 2), round(y0, 2), round(x1, 2), round(y1, 2))

    def u_range(self) -> tuple[float, float]:
        return (self.cu - (self.ox - self.box[0]) / self.scale, self.cu + (self.box[2] - self.ox) / self.scale)

    def v_range(self) -> tuple[float, float]:
        return (self.cv - (self.box[3] - self.oy) / self.scale, self.cv + (self.oy - self.box[1]) / self.scale)


def _draw_panel(
    image: Any,
    draw: Any,
    font: Any,
    text_h: int,
    view: _View,
    name: str,
    v_name: str,
    limits: EnvelopeLimits,
    geometry: _PlanGeometry | None,
    step: float,
) -> None:
    x0, y0, x1, y1 = view.box
    # panel name, centred above the plot; the vertical axis label above the vertical axis
    draw.text(((x0 + x1 - draw.textlength(name, font=font)) / 2, y0 - text_h - 3), name, fill=_TEXT, font=font)
    draw.text((x0 + 2, y0 - text_h - 3), f"{v_name} [m]", fill=_TEXT, font=font)
    draw.rectangle(view.box, outline=_FRAME, width=1)
    _draw_ticks(draw, font, text_h, view, step)

    # swept links first, so the translucent zones and the workspace outline stay visible over them
    if geometry is not None:
        _draw_sweep(image, view, geometry)
    draw.rectangle(view.rect(limits.workspace.lo, limits.workspace.hi), outline=_WORKSPACE, width=2)
    for zone in limits.keep_out:
        rect = view.rect(zone.lo, zone.hi)
        draw.rectangle(rect, fill=_KEEP_OUT_FILL, outline=_KEEP_OUT_EDGE, width=1)
    for zone in limits.keep_out:  # names on top of every fill, so overlapping zones stay legible
        rect = view.rect(zone.lo, zone.hi)
        draw.text((rect[0] + 2, rect[1] + 1), zone.name, fill=_KEEP_OUT_TEXT, font=font)

    # robot base at the origin, over the links
    bx, by = view.px(0.0, 0.0)
    draw.rectangle((bx - 5, by - 5, bx + 5, by + 5), fill=_BASE)
    if geometry is not None:
        path = view.pts(geometry.tcp_path)
        if len(path) > 1:
            draw.line(path, fill=_PATH, width=2, joint="curve")
        for px, py in view.pts(geometry.marks):
            arm = 5
            draw.line([(px - arm, py - arm), (px + arm, py + arm)], fill=_VIOLATION, width=3)
            draw.line([(px - arm, py + arm), (px + arm, py - arm)], fill=_VIOLATION, width=3)
        for (px, py), colour in ((path[0], _START), (path[-1], _GOAL)):  # small enough to leave the X visible
            draw.ellipse((px - 3, py - 3, px + 3, py + 3), fill=colour)

    # scale bar, right-aligned on the axis-label line below the plot
    bar = step * view.scale
    sx1, sy = x1 - 2, y1 + text_h + 6 + text_h / 2
    draw.line([(sx1 - bar, sy), (sx1, sy)], fill=_TEXT, width=2)
    for sx in (sx1 - bar, sx1):
        draw.line([(sx, sy - 3), (sx, sy + 3)], fill=_TEXT, width=1)
    label = f"{_fmt_m(step)} m"
    draw.text((sx1 - bar - 4 - draw.textlength(label, font=font), sy - text_h / 2 - 1), label, fill=_TEXT, font=font)


def _draw_sweep(image: Any, view: _View, geometry: _PlanGeometry) -> None:
    """Swept links: the union of all sampled capsules filled light grey, each sample outlined.

    Every capsule is a thick line with round caps (width ∝ radius) drawn into a mask, so
    overlapping capsules do not darken each other; the outline of each sampled pose is the
    mask's edge, darker for the goal pose.
    """
    from PIL import Image, ImageChops, ImageDraw, ImageFilter

    radii = geometry.radii.tolist()
    r_max = max(1.0, max(radii, default=0.0) * view.scale)
    samples = [view.pts(sample) for sample in geometry.capsules]
    xs = [p[0] for ends in samples for p in ends]
    ys = [p[1] for ends in samples for p in ends]
    if not xs:
        return
    # work only on the pixels the sweep can cover (within the plot)
    x0 = max(view.box[0], math.floor(min(xs) - r_max) - 2)
    y0 = max(view.box[1], math.floor(min(ys) - r_max) - 2)
    x1 = min(view.box[2], math.ceil(max(xs) + r_max) + 2)
    y1 = min(view.box[3], math.ceil(max(ys) + r_max) + 2)
    if x1 <= x0 or y1 <= y0:
        return
    w, h = x1 - x0 + 1, y1 - y0 + 1
    union = Image.new("L", (w, h), 0)
    edges = Image.new("L", (w, h), 0)
    goal_edges = edges
    for k, ends in enumerate(samples):
        mask = Image.new("L", (w, h), 0)
        pen = ImageDraw.Draw(mask)
        ends = [(px - x0, py - y0) for px, py in ends]
        for b, radius in enumerate(radii):
            r_px = float(max(1.0, radius * view.scale))  # a Python float: round() below gives an int on any numpy
            a, c = ends[2 * b], ends[2 * b + 1]
            pen.line([a, c], fill=255, width=max(1, round(2 * r_px)))
            for px, py in (a, c):
                pen.ellipse((px - r_px, py - r_px, px + r_px, py + r_px), fill=255)
        union = ImageChops.lighter(union, mask)
        outline = mask.filter(ImageFilter.FIND_EDGES)
        if k == len(samples) - 1:
            goal_edges = outline
        else:
            edges = ImageChops.lighter(edges, outline)
    image.paste(_LINK_FILL, (x0, y0), mask=union)
    image.paste(_LINK_EDGE, (x0, y0), mask=edges)
    image.paste(_LINK_GOAL, (x0, y0), mask=goal_edges)


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


__all__ = ["render_plan_preview"]
