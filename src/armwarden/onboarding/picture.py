"""A picture of the generated policy's arm at home: the plan preview's top and side views of a stay
at home, so a user sees the fitted bodies, the workspace box and the table before anything moves."""

from __future__ import annotations

import numpy as np

from armwarden.onboarding.home import stationary
from armwarden.preview.render import PlanPreviewer
from armwarden.safety.envelope import Envelope

#: [px] the picture (the plan preview's two views side by side)
PICTURE_SIZE = (960, 480)


def home_picture(envelope: Envelope, home: np.ndarray) -> bytes | None:
    """PNG bytes, or None when Pillow is missing."""
    trajectory = stationary(envelope, home)
    return PlanPreviewer(envelope.limits, PICTURE_SIZE).render(envelope.robot, trajectory, envelope.check(trajectory),
                                                                status="home")


__all__ = ["PICTURE_SIZE", "home_picture"]
