"""Robot backends behind one contract (`armwarden.backends.base`), looked up lazily by name.

Each backend module owns a strict pydantic `Config` and a factory
`create_backend(robot, policy, config) -> Backend`. Only the chosen backend's module is imported,
so `--backend fake` never imports mujoco, rclpy or python-can; a backend whose dependency is
missing raises `BackendUnavailable` (exit 2 at start-up), as python-can's interface registry does.
`--backend-config` files are read and validated here, in one place.

A third party adds a backend with an entry point in the group `armwarden.backends` (name → the
module that defines `Config` and `create_backend`), e.g. in its pyproject.toml::

    [project.entry-points."armwarden.backends"]
    myarm = "myarm_armwarden.backend"

A built-in name cannot be taken over: such an entry point is ignored, and said so on stderr.
"""

from __future__ import annotations

import functools
import importlib
import logging
from collections.abc import Mapping
from importlib.metadata import entry_points
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import yaml
from pydantic import BaseModel, ValidationError

from armwarden.core.errors import BackendUnavailable, ConfigurationError

if TYPE_CHECKING:
    from armwarden.backends.base import Backend
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

logger = logging.getLogger(__name__)

#: the entry-point group third-party backends register in (name -> module)
ENTRY_POINT_GROUP = "armwarden.backends"
#: the built-in backends: name -> module (which defines `Config` and `create_backend`)
BACKENDS: dict[str, str] = {
    "fake": "armwarden.backends.fake",
    "mujoco": "armwarden.backends.mujoco.backend",
    "can": "armwarden.backends.can.backend",
    "ros2": "armwarden.backends.ros2",
}
#: what each backend needs beyond the core install (`serve --help`); when it is missing, choosing
#: that backend refuses to start and names what to install
REQUIREMENTS: dict[str, str] = {
    "fake": "built in",
    "mujoco": "needs armwarden[mujoco]",
    "can": "needs armwarden[can]",
    "ros2": "needs rclpy and the ROS interfaces: tests_ros/README.md",
}
#: a backend config file larger than this is refused unread [bytes]
MAX_CONFIG_BYTES = 1_000_000


@functools.cache
def _entry_point_backends() -> tuple[tuple[str, str], ...]:
    """(name, module) of each backend installed packages register under `ENTRY_POINT_GROUP`
    (read once per process), by name."""
    return tuple(sorted((entry.name, entry.value) for entry in entry_points(group=ENTRY_POINT_GROUP)))


def registered_backends() -> dict[str, str]:
    """Every backend: the built-in ones, then the entry points' (none may take a name already given)."""
    found = dict(BACKENDS)
    for name, module in _entry_point_backends():
        if name in found:
            why = "a built-in backend" if name in BACKENDS else "registered already"
            logger.warning("ignoring the entry point %s = %s: %r is %s", name, module, name, why)
        else:
            found[name] = module
    return found


def backend_names() -> tuple[str, ...]:
    """Every name `--backend` accepts."""
    return tuple(registered_backends())


def backends_help() -> str:
    """`--backend`'s help: each backend with what it needs, and what happens when that is missing."""
    listed = ", ".join(f"{name} ({REQUIREMENTS.get(name, 'installed')})" for name in registered_backends())
    return f"robot backend: {listed}; a backend whose dependency is missing says so, and what to install, when chosen"


def backend_module(name: str) -> ModuleType:
    """Import the module of backend `name`; `BackendUnavailable` says why it cannot be used."""
    backends = registered_backends()
    if name not in backends:
        raise BackendUnavailable(f"unknown backend {name!r}; choose one of {', '.join(backends)}")
    try:
        module = importlib.import_module(backends[name])
    except ImportError as exc:
        install = f"install armwarden[{name}]" if name in BACKENDS else f"reinstall the package that registers {name!r}"
        raise BackendUnavailable(f"the {name} backend is not available: {exc}; {install}") from exc
    if not (isinstance(getattr(module, "Config", None), type) and callable(getattr(module, "create_backend", None))):
        raise BackendUnavailable(f"the {name} backend's module {backends[name]} defines no `Config` model and "
                                 "`create_backend` function")
    return module


def backend_config_model(name: str) -> type[BaseModel]:
    """The strict `Config` model of backend `name`."""
    return backend_module(name).Config


def parse_backend_config(name: str, document: Any, source: str = "<memory>") -> BaseModel:
    """Validate a backend config document (None or empty: all defaults). `ConfigurationError`
    lists every problem with its YAML path."""
    model = backend_config_model(name)
    if document is None:
        document = {}
    if not isinstance(document, Mapping):
        raise ConfigurationError(f"invalid {name} backend config {source}:\n  (document): must be a mapping of options")
    try:
        return model.model_validate(document)
    except ValidationError as exc:
        from armwarden.policy import validation_errors

        lines = "\n".join(f"  {path}: {message}" for path, message in validation_errors(exc, model))
        raise ConfigurationError(f"invalid {name} backend config {source}:\n{lines}") from None


def load_backend_config(name: str, path: str | Path | None) -> BaseModel:
    """Read and validate `--backend-config` for backend `name` (None: the defaults)."""
    if path is None:
        return parse_backend_config(name, None)
    source = str(path)
    try:
        raw = Path(path).expanduser().read_bytes()
        if len(raw) > MAX_CONFIG_BYTES:
            raise ConfigurationError(f"backend config {source} is larger than {MAX_CONFIG_BYTES} bytes")
        document = yaml.safe_load(raw.decode("utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigurationError(f"cannot read backend config {source}: {exc}") from exc
    return parse_backend_config(name, document, source)


def create_backend(name: str, robot: RobotModel, policy: Policy, config: BaseModel | Mapping[str, Any] | None = None) -> Backend:
    """Build backend `name` for `robot` under `policy`. `config` is the backend's `Config`, a
    mapping validated into one, or None for the defaults."""
    module = backend_module(name)
    if not isinstance(config, module.Config):
        config = parse_backend_config(name, dict(config) if isinstance(config, Mapping) else config)
    return module.create_backend(robot, policy, config)


__all__ = [
    "BACKENDS",
    "ENTRY_POINT_GROUP",
    "REQUIREMENTS",
    "backend_config_model",
    "backend_module",
    "backend_names",
    "backends_help",
    "create_backend",
    "load_backend_config",
    "parse_backend_config",
    "registered_backends",
]
