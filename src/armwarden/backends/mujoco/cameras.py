"""The MuJoCo cell's offscreen cameras: the published configuration of every body, rendered to PNG.

One thread of their own owns the renderer (its GL context is current there), off the physics
thread, so rendering never holds up the physics. The renderer is made by the first snapshot, not
at open (most sessions never look). That first frame (GL context, shaders, the model's meshes and
textures uploaded) took 1.2–1.5 s with software EGL on a loaded 2-core machine, the next ones
0.2–0.35 s: it is the one-time setup `SimulatedCameras.setup_timeout_s` allows for, and
`set_up` says when it is done.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import asyncio
import io
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from armwarden.backends.parts import Cameras
from armwarden.backends.values import CameraImage
from armwarden.core.errors import BackendError

#: extra deadline [s] for the first camera snapshot, which creates the renderer and draws its first
#: frame (1.2–1.5 s measured on a loaded 2-core machine with software EGL, vs 0.2–0.35 s after)
RENDERER_SETUP_TIMEOUT_S = 15.0


class SimulatedCameras(Cameras):
    """The camera part of the MuJoCo cell: `scene()` (the latest published configuration of every
    body and its stamp) rendered by `renderer`."""

    setup_timeout_s = RENDERER_SETUP_TIMEOUT_S

    def __init__(self, renderer: OffscreenCameras, names: tuple[str, ...],
                 scene: Callable[[], tuple[np.ndarray, float]]) -> None:
        self._renderer, self._names, self._scene = renderer, names, scene

    @property
    def names(self) -> tuple[str, ...]:
        return self._names

    def set_up(self) -> bool:
        return self._renderer.set_up

    async def snapshot(self, camera: str) -> CameraImage:
        qpos, stamp = self._scene()
        return await self._renderer.snapshot(camera, qpos, stamp)


class OffscreenCameras:
    """The named cameras of one MuJoCo model, rendered at `size_px` (width, height) [px]."""

    def __init__(self, model: mujoco.MjModel, size_px: tuple[int, int]) -> None:
        self._model = model
        #: rendered image size (width, height) [px]
        self.size_px = size_px
        self._pool: ThreadPoolExecutor | None = None
        self._renderer: mujoco.Renderer | None = None
        self._data: mujoco.MjData | None = None
        self._rendered = threading.Event()  # a frame has been rendered: the one-time setup is done

    @property
    def set_up(self) -> bool:
        """Whether the renderer exists and has drawn a frame."""
        return self._rendered.is_set()

    async def snapshot(self, camera: str, qpos: np.ndarray, stamp: float) -> CameraImage:
        """Event loop: the configuration `qpos` (every body's) seen by `camera`, stamped `stamp`."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="armwarden-mujoco-render")
        png = await asyncio.wrap_future(self._pool.submit(self._render_png, camera, qpos))
        width, height = self.size_px
        return CameraImage(camera, width, height, png, stamp)

    async def close(self) -> None:
        """Event loop: release the renderer on its own thread, then end that thread."""
        pool, self._pool = self._pool, None
        if pool is not None:
            await asyncio.wrap_future(pool.submit(self._close_renderer))
            pool.shutdown(wait=False)

    def _render_png(self, camera: str, qpos: np.ndarray) -> bytes:
        """Render thread: the published configuration seen by `camera`, as PNG bytes."""
        from PIL import Image  # the render path only (Pillow is a core dependency)

        width, height = self.size_px
        renderer, data = self._renderer, self._data
        if renderer is None or data is None:
            try:
                renderer = self._renderer = mujoco.Renderer(self._model, height, width)
            except (mujoco.FatalError, RuntimeError) as exc:
                raise BackendError(
                    f"cannot render offscreen ({exc}); MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} when mujoco was "
                    "imported: import armwarden.backends.mujoco before mujoco, or set MUJOCO_GL=egl"
                ) from exc
            data = self._data = mujoco.MjData(self._model)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(self._model, data)
        mujoco.mj_camlight(self._model, data)
        renderer.update_scene(data, camera=camera)
        buffer = io.BytesIO()
        Image.fromarray(renderer.render()).save(buffer, format="PNG")
        self._rendered.set()
        return buffer.getvalue()

    def _close_renderer(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


__all__ = ["OffscreenCameras"]
