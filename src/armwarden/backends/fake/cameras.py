"""The fake backend's cameras: a deterministic top view of the table, the base and the TCP.

Pillow is a core dependency; in a broken install without it `HAVE_PILLOW` is false and the fake
declares no cameras (`armwarden serve` says so at start-up). `FakeCameras` is the cameras part of
the fake cell: each snapshot renders what the backend last published (`TopView`) off the event loop.
"""

from __future__ import annotations

import importlib.util
import io
import math
from collections.abc import Callable
from dataclasses import dataclass

import anyio
import numpy as np

from armwarden.backends.parts import Cameras
from armwarden.backends.values import CameraImage

#: False only in a broken install (Pillow is a core dependency): the fake then has no cameras
#: (imported where an image is drawn)
HAVE_PILLOW = importlib.util.find_spec("PIL") is not None

#: camera image size [px]
CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX = 320, 240


def render_top_view(
    camera: str, frame: int, tcp: np.ndarray, gripper_width_m: float, force_z_n: float, table_height_m: float | None
) -> bytes:
    """A deterministic top view (x up, y left): the table and workspace, the base and the TCP dot.

    "scene" shows the whole workspace at 200 px/m; any other camera ("wrist") is centred on the
    TCP at 800 px/m and also draws the fingers at the current opening.
    """
    if camera == "scene":
        centre_x, centre_y, scale = 0.4, 0.0, 200.0
    else:
        centre_x, centre_y, scale = float(tcp[0]), float(tcp[1]), 800.0

    def to_px(x: float, y: float) -> tuple[float, float]:
        return (CAMERA_WIDTH_PX / 2 - (y - centre_y) * scale, CAMERA_HEIGHT_PX / 2 - (x - centre_x) * scale)

    from PIL import Image, ImageDraw  # the fake declares no cameras without Pillow (a broken install)

    image = Image.new("RGB", (CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX), (200, 170, 130) if table_height_m is not None else (90, 90, 90))
    draw = ImageDraw.Draw(image)
    grid_m = 0.1 if camera == "scene" else 0.05
    half_w, half_h = CAMERA_WIDTH_PX / 2 / scale, CAMERA_HEIGHT_PX / 2 / scale
    for k in range(math.floor((centre_y - half_w) / grid_m), math.ceil((centre_y + half_w) / grid_m) + 1):
        u, _ = to_px(0.0, k * grid_m)
        draw.line([(u, 0), (u, CAMERA_HEIGHT_PX)], fill=(150, 130, 100))
    for k in range(math.floor((centre_x - half_h) / grid_m), math.ceil((centre_x + half_h) / grid_m) + 1):
        _, v = to_px(k * grid_m, 0.0)
        draw.line([(0, v), (CAMERA_WIDTH_PX, v)], fill=(150, 130, 100))
    bu, bv = to_px(0.0, 0.0)
    base_r = 0.08 * scale
    draw.ellipse([bu - base_r, bv - base_r, bu + base_r, bv + base_r], fill=(230, 230, 230), outline=(40, 40, 40))
    tu, tv = to_px(float(tcp[0]), float(tcp[1]))
    if camera != "scene":  # the fingers, seen from above, across y
        for side in (-1, 1):
            fu = tu + side * (gripper_width_m / 2 + 0.005) * scale
            draw.rectangle([fu - 0.005 * scale, tv - 0.01 * scale, fu + 0.005 * scale, tv + 0.01 * scale], fill=(60, 60, 60))
    dot_r = 5
    colour = (220, 30, 30) if force_z_n > 0 else (30, 90, 220)
    draw.ellipse([tu - dot_r, tv - dot_r, tu + dot_r, tv + dot_r], fill=colour, outline=(0, 0, 0))
    draw.text((4, 4), f"{camera} #{frame}", fill=(0, 0, 0))
    draw.text((4, CAMERA_HEIGHT_PX - 14), f"tcp {tcp[0]:+.3f} {tcp[1]:+.3f} {tcp[2]:+.3f} m", fill=(0, 0, 0))
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


@dataclass(frozen=True)
class TopView:
    """What a top view shows: the published sample's stamp (monotonic) and TCP position [m], the
    finger opening [m], the contact force [N] and the table's height [m] (None: no table)."""

    stamp: float
    tcp: np.ndarray
    gripper_width_m: float
    force_z_n: float
    table_height_m: float | None


class FakeCameras(Cameras):
    """The cameras part of the fake cell: `names`, each with a frame counter drawn on its images."""

    def __init__(self, names: tuple[str, ...], view: Callable[[], TopView]) -> None:
        self._names = names
        self._view = view  # what the backend last published
        self._frames = dict.fromkeys(names, 0)

    @property
    def names(self) -> tuple[str, ...]:
        return self._names

    async def snapshot(self, camera: str) -> CameraImage:
        self._frames[camera] += 1
        frame = self._frames[camera]
        view = self._view()
        png = await anyio.to_thread.run_sync(render_top_view, camera, frame, view.tcp.copy(), view.gripper_width_m,
                                             view.force_z_n, view.table_height_m)
        return CameraImage(camera, CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX, png, view.stamp)


__all__ = ["CAMERA_HEIGHT_PX", "CAMERA_WIDTH_PX", "HAVE_PILLOW", "FakeCameras", "TopView", "render_top_view"]
