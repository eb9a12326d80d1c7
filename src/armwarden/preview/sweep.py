"""The links a plan sweeps, drawn into a scene's canvas: every sampled capsule as a mask, the
masks' union filled and each sample outlined, all pixels then taken from the scene's layers.

The costliest part of a preview, so it works on NumPy masks packed one bit per sample and draws
with Pillow's primitives straight on their memory (see `draw_sweeps`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from armwarden.preview.images import mask_image
from armwarden.preview.scene import Scene, SweepLayers


def draw_sweeps(scene: Scene, capsules: np.ndarray, radii: np.ndarray) -> None:
    """Swept links in every panel: the union of all sampled capsules (`capsules` (S, B, 2, 3):
    sample, capsule, end point; `radii` (B,)) filled light grey, each sample outlined.

    Every capsule is a thick line with round caps (width ∝ radius) drawn into its sample's mask,
    so overlapping capsules do not darken each other; the outline of each sampled pose is its
    mask's edge (mask pixels with a background pixel among their 8 neighbours; the edge of the
    region a panel's sweep can cover counts as background), darker for the goal pose.

    Both panels' samples are drawn into one tall mask, one band per panel and sample; the bands
    are then packed into one bit per sample in each pixel's byte(s), so the union and every
    sample's outline are computed at once, on an eighth of the bytes. Each pixel of the canvas
    is then taken from the panel's layer (`Scene.under`) of its colour: the zones and the base
    over it come with it.
    """
    from PIL import ImageDraw

    if not capsules.size:
        return
    radius_list = radii.tolist()
    n_samples = len(capsules)
    scale = scene.views[0].scale  # one scale for every panel
    r_max = max(1.0, max(radius_list, default=0.0) * scale)
    regions: list[_SweepRegion] = []
    for view, under in zip(scene.views, scene.under, strict=True):
        xs, ys = view.coordinates(capsules)  # every sample's end points in one pass
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
    r_pxs = [float(max(1.0, radius * scale)) for radius in radius_list]  # Python floats: round() gives an int
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
    pixels (flattened, as `View.coordinates` gives them), and where the region lies in the picture."""

    under: SweepLayers
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
