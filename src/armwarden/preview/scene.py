"""The static scene of a plan preview: what every plan drawn at one picture scale shares.

Drawn once per scale and kept by `PlanPreviewer`: each panel's pixel mapping (`View`), the frames,
ticks, labels and scale bars, the zones and the base, the layers the sweep's pixels are chosen from
(`SweepLayers`), and text rendered once as coverage masks (`TextStamp`), so that a plan's picture
costs only its own strokes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from armwarden.preview import palette
from armwarden.preview.images import BandedPngEncoder, rgbx_image, rgbx_words

if TYPE_CHECKING:  # pragma: no cover
    from armwarden.safety.limits import EnvelopeLimits

_NICE_STEPS = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0)


class Scene:
    """What every plan drawn at one scale shares: each panel's `View`; the picture with the panel
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
        image = Image.new("RGB", (width, height), palette.WHITE)
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

        self._stamps: dict[tuple[str, float, float], TextStamp] = {}
        self._lengths: dict[str, float] = {}
        self.views: list[View] = []
        for index, (axis_v, name) in enumerate(((1, "TOP (x-y)"), (2, "SIDE (x-z)"))):
            left = index * panel_w + margin_l
            box = (left, top + margin_t, left + plot_w, top + margin_t + plot_h)
            view = View(box, scale, lo, hi, axis_v)
            _draw_frame(draw, font, text_h, view, name, "xyz"[axis_v], step)
            self.views.append(view)
            if index == 0:
                draw.line([(panel_w, top), (panel_w, height - 2)], fill=palette.SEPARATOR, width=1)

        layers = [rgbx_words(self._overlaid(image, limits, None))]
        layers += [rgbx_words(self._overlaid(image, limits, colour)) for colour in palette.SWEEP_COLOURS]
        self.under = [SweepLayers(layers, view.box) for view in self.views]
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
            stamp = self._stamps[key] = TextStamp(self.font, text, xy)
        stamp.paste(image, fill, shift)


class SweepLayers:
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


class TextStamp:
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


class View:
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



def _draw_frame(draw: Any, font: Any, text_h: int, view: View, name: str, v_name: str, step: float) -> None:
    """A panel's static parts: name, axis labels, frame, ticks and the scale bar (below the plot)."""
    x0, y0, x1, y1 = view.box
    # panel name, centred above the plot; the vertical axis label above the vertical axis
    draw.text(((x0 + x1 - draw.textlength(name, font=font)) / 2, y0 - text_h - 3), name, fill=palette.TEXT, font=font)
    draw.text((x0 + 2, y0 - text_h - 3), f"{v_name} [m]", fill=palette.TEXT, font=font)
    draw.rectangle(view.box, outline=palette.FRAME, width=1)
    _draw_ticks(draw, font, text_h, view, step)

    # scale bar, right-aligned on the axis-label line below the plot
    bar = step * view.scale
    sx1, sy = x1 - 2, y1 + text_h + 6 + text_h / 2
    draw.line([(sx1 - bar, sy), (sx1, sy)], fill=palette.TEXT, width=2)
    for sx in (sx1 - bar, sx1):
        draw.line([(sx, sy - 3), (sx, sy + 3)], fill=palette.TEXT, width=1)
    label = f"{_fmt_m(step)} m"
    draw.text((sx1 - bar - 4 - draw.textlength(label, font=font), sy - text_h / 2 - 1), label, fill=palette.TEXT, font=font)


def _draw_overlay(image: Any, draw: Any, scene: Scene, view: View, limits: EnvelopeLimits) -> None:
    """What a panel draws over the swept links, the same for every plan: the workspace outline,
    the zones (translucent, so the links stay visible under them), their names and the base."""
    draw.rectangle(view.rect(limits.workspace.lo, limits.workspace.hi), outline=palette.WORKSPACE, width=2)
    for zone in limits.keep_out:
        rect = view.rect(zone.lo, zone.hi)
        draw.rectangle(rect, fill=palette.KEEP_OUT_FILL, outline=palette.KEEP_OUT_EDGE, width=1)
    for zone in limits.keep_out:  # names on top of every fill, so overlapping zones stay legible
        rect = view.rect(zone.lo, zone.hi)
        scene.text(image, (rect[0] + 2, rect[1] + 1), zone.name, palette.KEEP_OUT_TEXT)
    # robot base at the origin, over the links
    bx, by = view.px(0.0, 0.0)
    draw.rectangle((bx - 5, by - 5, bx + 5, by + 5), fill=palette.BASE)



def _draw_ticks(draw: Any, font: Any, text_h: int, view: View, step: float) -> None:
    x0, _, x1, y1 = view.box
    u_lo, u_hi = view.u_range()
    for k in range(math.ceil(u_lo / step), math.floor(u_hi / step) + 1):
        px, _ = view.px(k * step, 0.0)
        draw.line([(px, y1), (px, y1 + 3)], fill=palette.FRAME, width=1)
        label = _fmt_m(k * step)
        draw.text((px - draw.textlength(label, font=font) / 2, y1 + 4), label, fill=palette.TEXT, font=font)
    axis = "x [m]"
    draw.text(((x0 + x1 - draw.textlength(axis, font=font)) / 2, y1 + text_h + 6), axis, fill=palette.TEXT, font=font)
    v_lo, v_hi = view.v_range()
    for k in range(math.ceil(v_lo / step), math.floor(v_hi / step) + 1):
        _, py = view.px(0.0, k * step)
        draw.line([(x0 - 3, py), (x0, py)], fill=palette.FRAME, width=1)
        label = _fmt_m(k * step)
        draw.text((x0 - 4 - draw.textlength(label, font=font), py - text_h / 2 - 1), label, fill=palette.TEXT, font=font)


def _fmt_m(value: float) -> str:
    text = f"{value:.2f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _text_height(draw: Any, font: Any) -> int:
    box = draw.textbbox((0, 0), "Hg[0.5]", font=font)
    return int(box[3] - min(box[1], 0))

