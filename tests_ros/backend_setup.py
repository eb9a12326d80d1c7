"""Building the ROS 2 backend for tests: examples/ros2_fr3.yaml (the cell's names) with changes."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import yaml

from armwarden.backends import parse_backend_config
from armwarden.backends.ros2.backend import Ros2Backend, create_backend
from armwarden.backends.ros2.config import Config
from armwarden.policy import bundled_policy, load_policy
from armwarden.robot import build_robot

POLICY = load_policy(bundled_policy("fr3"))
ROBOT = build_robot(POLICY)
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ros2_fr3.yaml"


def example_document(**changes: Any) -> dict[str, Any]:
    """The example with `changes`; without a guardian process unless `guardian` is among them (as
    the harness: a second of rclpy start-up and one more DDS participant per backend; the guardian's
    own tests and every daemon a test starts from examples/ros2_fr3.yaml have it)."""
    document = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    document["guardian"] = None
    document.update(changes)
    return document


def example_config(**changes: Any) -> Config:
    """examples/ros2_fr3.yaml with top-level keys replaced."""
    config = parse_backend_config("ros2", example_document(**changes), str(EXAMPLE))
    assert isinstance(config, Config)
    return config


def build_backend(config: Config | None = None) -> Ros2Backend:
    return create_backend(ROBOT, POLICY, config or example_config())


@contextlib.asynccontextmanager
async def opened(config: Config | None = None) -> AsyncIterator[Ros2Backend]:
    """An open backend (closed afterwards)."""
    backend = build_backend(config)
    await backend.open()
    try:
        yield backend
    finally:
        await backend.close()
