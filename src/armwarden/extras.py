"""Optional dependencies, the features each one gives, and the start-up lines of `serve` that
name every feature an absent one removes.

Found in a first hour (issue 31): an install without Pillow silently lost `camera_snapshot` and
every plan preview picture, and nothing in the log said why. Now `serve` logs one line per
missing dependency (Pillow at WARNING, naming the tools the policy enables that lose pictures; a
backend's dependency at INFO, as the backend itself refuses clearly when chosen), or one INFO
line saying every feature is available.

A backend's dependency is looked up without being imported (`importlib.util.find_spec`):
importing mujoco or rclpy costs time and memory a fake-backend daemon never needs. Pillow, a
core dependency every plan preview uses, is imported, so a broken install counts as missing.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import sys
from collections.abc import Collection
from dataclasses import dataclass

from armwarden.tools import TOOLS

#: the tools whose pictures need Pillow: a camera image wider than the policy's
#: `perception.max_image_width` is shrunk with it (and the MuJoCo backend renders every camera
#: with it); the plan tools draw their preview with it
PICTURE_TOOLS: tuple[str, ...] = tuple(spec.name for spec in TOOLS if spec.picture)

ALL_AVAILABLE = "every optional feature is available: Pillow (camera pictures, plan previews), mujoco, can and ros2 backends"


@dataclass(frozen=True)
class OptionalDependency:
    """One dependency a feature needs; `modules` must all be importable."""

    package: str
    modules: tuple[str, ...]
    removes: str
    install: str
    level: int
    #: import the modules (a cheap core dependency: a broken install counts as missing) rather
    #: than only finding them
    load: bool = False


DEPENDENCIES: tuple[OptionalDependency, ...] = (
    OptionalDependency("Pillow", ("PIL.Image",), "pictures", "Pillow is a core dependency: reinstall armwarden "
                       "(pip install pillow)", logging.WARNING, load=True),
    OptionalDependency("mujoco", ("mujoco",), "the mujoco backend", "pip install 'armwarden[mujoco]'", logging.INFO),
    OptionalDependency("python-can", ("can",), "the can backend", "pip install 'armwarden[can]'", logging.INFO),
    OptionalDependency("rclpy and control_msgs", ("rclpy", "control_msgs"), "the ros2 backend",
                       "from a checkout, `bash scripts/run.sh --backend ros2 ...` sets up and serves from .venv-ros, "
                       "a venv of its own (README)",
                       logging.INFO),
)


def why_missing(dependency: OptionalDependency) -> str | None:
    """None when every module of `dependency` is there, else why one is not. Never raises."""
    for name in dependency.modules:
        try:
            if dependency.load:
                importlib.import_module(name)
                continue
            if sys.modules.get(name) is not None:  # already imported
                continue
            if importlib.util.find_spec(name) is None:
                return f"No module named {name!r}"
        except Exception as exc:  # ImportError, or whatever a broken package raises as it loads
            return f"{type(exc).__name__}: {exc}"
    return None


def _pictures_lost(enabled: Collection[str] | None) -> str:
    """What a missing Pillow takes from the picture tools `enabled` enables (None: all of them)."""
    tools = [tool for tool in PICTURE_TOOLS if enabled is None or tool in enabled]
    lost = []
    if "camera_snapshot" in tools:
        lost.append("camera_snapshot (the fake's camera is not served, MuJoCo's cannot render, and an image wider "
                    "than the policy's max_image_width is refused)")
    previews = [tool for tool in tools if tool != "camera_snapshot"]
    if previews:
        lost.append(f"the preview pictures of {', '.join(previews)}")
    return f"lost: {'; '.join(lost)}" if lost else "no tool this policy enables draws a picture"


def feature_lines(enabled: Collection[str] | None = None) -> list[tuple[int, str]]:
    """(level, message) for each absent dependency and what it removes, or one INFO line that
    all is available. `enabled`: the tool names the policy enables (None: all of them); the
    backend's capabilities are not asked, as the fake serves no camera without Pillow."""
    lines: list[tuple[int, str]] = []
    for dependency in DEPENDENCIES:
        why = why_missing(dependency)
        if why is None:
            continue
        removes = _pictures_lost(enabled) if dependency.removes == "pictures" else f"{dependency.removes} is unavailable"
        lines.append((dependency.level, f"{dependency.package} missing ({why}): {removes}; {dependency.install}"))
    return lines or [(logging.INFO, ALL_AVAILABLE)]


def log_feature_lines(logger: logging.Logger, enabled: Collection[str] | None = None) -> None:
    """Log `feature_lines` (stderr: the daemon's logging)."""
    for level, message in feature_lines(enabled):
        logger.log(level, message)


__all__ = ["ALL_AVAILABLE", "DEPENDENCIES", "PICTURE_TOOLS", "OptionalDependency", "feature_lines",
           "log_feature_lines", "why_missing"]
