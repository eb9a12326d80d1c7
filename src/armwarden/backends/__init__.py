"""Robot backends behind one async protocol, looked up lazily by name.

Only the chosen backend's module is imported, so `--backend fake` never imports mujoco, rclpy
or python-can; a backend whose dependency is missing raises `BackendUnavailable` (exit 2).
"""

from __future__ import annotations

import importlib
from typing import Any

from armwarden.errors import BackendUnavailable

# name -> (module, factory function); the factory takes (robot, policy, config_path, **options)
BACKENDS: dict[str, tuple[str, str]] = {
    "fake": ("armwarden.backends.fake", "create_backend"),
    "mujoco": ("armwarden.backends.mujoco", "create_backend"),
    "ros2": ("armwarden.backends.ros2", "create_backend"),
    "can": ("armwarden.backends.can", "create_backend"),
}


def create_backend(name: str, **kwargs: Any):  # -> Backend (import cycle kept out of the hot path)
    """Import and build the backend called `name`; a clear `BackendUnavailable` otherwise."""
    if name not in BACKENDS:
        raise BackendUnavailable(f"unknown backend {name!r}; choose one of {', '.join(BACKENDS)}")
    module_name, factory_name = BACKENDS[name]
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise BackendUnavailable(
            f"backend {name!r} is not available: {exc}. Install its extra, e.g. pip install 'armwarden[{name}]'"
        ) from exc
    return getattr(module, factory_name)(**kwargs)
