"""The robots ArmWarden ships, one folder each (`robots/<name>/`): its description, fitted
collision geometry, bundled policies and the profile that indexes them (`profile.yaml`).

`builtin:<name>` in a policy (`robot.description`, `robot.collision_geometry`) names such a
folder; `bundled_policy` finds a bundled policy by name. Adding a robot is a folder here
(docs/add-a-robot.md); nothing in the code names one.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from armwarden.core.errors import RobotModelError

BUILTIN_PREFIX = "builtin:"
PROFILE_FILE = "profile.yaml"
#: a file inside the robot's folder (no path separators: a profile cannot point outside it)
FileName = Annotated[str, Field(min_length=1, max_length=128, pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")]


class RobotProfile(BaseModel):
    """One robot's `profile.yaml`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["armwarden-robot-profile/1"]
    name: Annotated[str, Field(pattern=r"^[a-z0-9_]+$")]
    title: str
    description: FileName = Field(description="the URDF")
    collision_geometry: FileName | None = Field(default=None, description="fitted collision geometry, if any")
    policies: dict[Annotated[str, Field(pattern=r"^[a-z0-9_]+$")], FileName] = Field(
        min_length=1, description="bundled policies by name; the first is the robot's default")

    def file(self, name: str) -> Path:
        """The path of a file of this profile's folder."""
        return _robots_dir() / self.name / name


def _robots_dir() -> Path:
    return Path(str(resources.files("armwarden") / "robots"))


@functools.cache
def builtin_robots() -> tuple[str, ...]:
    """The names of the robots shipped (each folder with a profile), sorted."""
    return tuple(sorted(path.parent.name for path in _robots_dir().glob(f"*/{PROFILE_FILE}")))


@functools.cache
def load_profile(name: str) -> RobotProfile:
    """The profile of the shipped robot `name`; RobotModelError for an unknown or invalid one."""
    if name not in builtin_robots():
        raise RobotModelError(f"unknown built-in robot {name!r}; available: "
                              + ", ".join(BUILTIN_PREFIX + robot for robot in builtin_robots()))
    path = _robots_dir() / name / PROFILE_FILE
    try:
        profile = RobotProfile.model_validate(yaml.safe_load(path.read_text(encoding="utf-8")))
    except (OSError, yaml.YAMLError, ValidationError) as exc:
        raise RobotModelError(f"the robot profile {path} is invalid: {exc}") from exc
    if profile.name != name:
        raise RobotModelError(f"the robot profile {path} names the robot {profile.name!r}, its folder {name!r}")
    return profile


def bundled_policies() -> dict[str, Path]:
    """Every bundled policy by name, across the shipped robots."""
    return {policy: load_profile(robot).file(file) for robot in builtin_robots()
            for policy, file in load_profile(robot).policies.items()}


__all__ = ["BUILTIN_PREFIX", "RobotProfile", "builtin_robots", "bundled_policies", "load_profile"]
