"""The console's camera view: each camera's latest picture, read the way `camera_snapshot` reads it.

Why this shape:
- One path to the backend. A picture is read through `Guard.camera` (`guard/readings.py`), the
  body of the MCP tool `camera_snapshot`: the policy's `perception` tool group and camera
  allowlist (`safety.checks.check_camera`, which the page also asks), the backend's deadline,
  its failures turned into refusals, the policy's image width. The backend sees one kind of
  request whoever asks.
- The policy's rate limits apply, on a budget of the console's own: every camera may be read as
  often as the policy lets `camera_snapshot` be called, all of them together as often as its
  global limit allows (`rate_limits`). The console's reads do not spend the agent's tokens (a
  page left open would otherwise starve the agent of pictures, and of every other tool through
  the global bucket), and the agent's calls do not blank the operator's view.
- Viewers share reads. A camera's latest outcome (its picture, or why there is none) is kept for
  `refresh_s`; every request in that time gets it, and requests that arrive while a read is under
  way wait for that read. However many pages are open, the backend sees at most one read per
  camera per `refresh_s`, and the page polls at that interval.
- Nothing here is audited: like the console's other reads (the live sections, the top/side
  view) a picture fetched by a signed-in session leaves no record, so an open page cannot flood
  the audit log, and the pixels never reach it. A camera that starts or stops failing is logged
  on stderr once per change.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import anyio

from armwarden.core.errors import SafetyRefusal
from armwarden.guard import Guard
from armwarden.safety import checks
from armwarden.safety.ratelimit import RateLimiter

__all__ = ["CameraFeed", "CameraPicture", "CameraTrouble", "CameraView"]

logger = logging.getLogger(__name__)

#: the fastest the page asks for a new picture [s], whatever the rate limits allow
MIN_REFRESH_S = 1.0
#: the kinds of trouble a camera can be in, each with the HTTP status the picture route answers
TroubleKind = Literal["not_allowed", "failed", "rate_limited"]
STATUS_OF: dict[TroubleKind, int] = {"not_allowed": 403, "failed": 503, "rate_limited": 429}


@dataclass(frozen=True)
class CameraPicture:
    """A camera's latest picture as `camera_snapshot` returns it (PNG, downscaled to the policy's width)."""

    png: bytes
    width: int
    height: int
    stamp: float  # the backend's stamp of the image
    at: float  # when it was read, on the console's clock


@dataclass(frozen=True)
class CameraTrouble:
    """Why a camera has no picture now; `at`: when that was found, on the console's clock."""

    kind: TroubleKind
    message: str
    at: float

    @property
    def status(self) -> int:
        return STATUS_OF[self.kind]


@dataclass(frozen=True)
class CameraView:
    """One camera on the page: its name, whether the policy lets it be read, and the last trouble."""

    name: str
    allowed: bool
    error: str | None


class CameraFeed:
    """The latest picture of each camera the backend declares, for the console; one per console."""

    def __init__(self, guard: Guard, clock: Callable[[], float] = time.monotonic) -> None:
        self.guard = guard
        self._clock = clock
        limits = guard.policy.rate_limits
        per_camera = limits.limit_for("camera_snapshot")
        self.cameras: tuple[str, ...] = tuple(guard.capabilities.cameras)
        #: how long an outcome is kept, and how often the page asks: no faster than one camera's
        #: rate, nor than the global rate shared by all of them
        self.refresh_s = max(MIN_REFRESH_S, 60.0 / per_camera, 60.0 * len(self.cameras) / limits.global_per_minute)
        self._limiter = RateLimiter(limits.global_per_minute, per_camera, exempt=(), clock=clock)
        self._latest: dict[str, CameraPicture | CameraTrouble] = {}
        self._pictures: dict[str, CameraPicture] = {}
        self._locks = {name: anyio.Lock() for name in self.cameras}

    @property
    def refresh_ms(self) -> int:
        return math.ceil(self.refresh_s * 1000)

    def allowed(self, camera: str) -> bool:
        return self._refusal(camera) is None

    def _refusal(self, camera: str) -> SafetyRefusal | None:
        """Why the policy lets no one read `camera` (the Guard's own check), or None."""
        try:
            checks.check_camera(self.guard.policy, camera)
        except SafetyRefusal as exc:
            return exc
        return None

    def views(self) -> list[CameraView]:
        """The cameras for the page, with what is already known (no backend read here)."""
        views = []
        for name in self.cameras:
            latest = self._latest.get(name)
            error = latest.message if isinstance(latest, CameraTrouble) else None
            refusal = self._refusal(name)
            if refusal is not None:
                error = self._not_allowed(refusal).message
            views.append(CameraView(name, refusal is None, error))
        return views

    def unknown(self, camera: str) -> str:
        """The message for a camera the backend does not declare."""
        shown = repr(camera[:64])
        if not self.cameras:
            return f"no camera {shown}: this backend has no cameras"
        return f"no camera {shown}: this backend's cameras are {', '.join(self.cameras)}"

    async def latest(self, camera: str) -> CameraPicture | CameraTrouble:
        """`camera`'s latest picture, or why there is none. Reads the backend through the Guard
        only when the last outcome is older than `refresh_s` and the rate limits allow; a read
        the limits refuse keeps the last picture (or says when to retry). `camera` must be one
        of `cameras` (KeyError otherwise)."""
        lock = self._locks[camera]
        refusal = self._refusal(camera)
        if refusal is not None:
            return self._not_allowed(refusal)
        async with lock:  # viewers that arrive during a read get its outcome
            now = self._clock()
            latest = self._latest.get(camera)
            if latest is not None and now - latest.at < self.refresh_s:
                return latest
            decision = self._limiter.try_acquire(camera)
            if not decision.allowed:
                kept = self._pictures.get(camera)
                if kept is not None:
                    return kept
                if decision.scope == "tool":
                    why = (f"camera {camera!r} may be read at most {decision.limit_per_minute} times per minute "
                           "(the policy's rate limit of camera_snapshot)")
                else:
                    why = (f"the console's cameras may be read at most {decision.limit_per_minute} times per minute "
                           "together (the policy's global rate limit)")
                return CameraTrouble("rate_limited", f"rate limit: {why}; retry in {decision.retry_after_s:.1f} s", now)
            outcome = await self._read(camera)
            self._note(camera, latest, outcome)
            return outcome

    async def _read(self, camera: str) -> CameraPicture | CameraTrouble:
        try:
            width, height, stamp, png = await self.guard.camera(camera)
        except SafetyRefusal as exc:
            return CameraTrouble("failed", f"{exc.code}: {exc}", self._clock())
        return CameraPicture(png, width, height, stamp, self._clock())

    def _note(self, camera: str, before: CameraPicture | CameraTrouble | None,
              outcome: CameraPicture | CameraTrouble) -> None:
        """Keep `outcome`; log a camera that starts failing, fails otherwise, or recovers."""
        self._latest[camera] = outcome
        if isinstance(outcome, CameraPicture):
            self._pictures[camera] = outcome
            if isinstance(before, CameraTrouble):
                logger.info("console camera %s: pictures again", camera)
        elif not isinstance(before, CameraTrouble) or before.message != outcome.message:
            logger.warning("console camera %s: %s", camera, outcome.message)

    def _not_allowed(self, refusal: SafetyRefusal) -> CameraTrouble:
        return CameraTrouble("not_allowed", f"{refusal.code}: {refusal}", self._clock())
