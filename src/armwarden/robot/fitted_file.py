"""The fitted-geometry data file: capsules per link, fitted to a robot's collision meshes, and the
self-collision pair analysis — its data model, `load_fitted` (every robot model reads it at run
time, so this module needs nothing beyond the runtime's dependencies) and `render_fitted`, which
writes the same bytes for the same fit. The fitting itself is `armwarden.robot.fitting`."""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, field_validator

from armwarden.core.errors import ArmWardenError

__all__ = [
    "FORMAT",
    "ExcludedPair",
    "FittedBody",
    "FittedGeometry",
    "FittingError",
    "LinkFit",
    "load_fitted",
    "render_fitted",
]

FORMAT = "armwarden-fitted-geometry/1"


class FittingError(ArmWardenError):
    """A fit that does not hold its mesh, or a data file that does not parse."""


@dataclass(frozen=True)
class FittedBody:
    """A capsule in its link's frame: segment `p0_m`–`p1_m` swept by a ball of `radius_m` [m]."""

    name: str
    p0_m: tuple[float, float, float]
    p1_m: tuple[float, float, float]
    radius_m: float


@dataclass(frozen=True)
class LinkFit:
    """The fitted capsules of one link and how well they fit."""

    link: str
    source: str
    bodies: tuple[FittedBody, ...]
    n_vertices: int
    n_triangles: int
    worst_over_approximation_m: float
    #: the worst over-approximation for each number of capsules tried (1, 2, …), measured on
    #: points twice as far apart as the reported figure's; for a mesh of several parts, that of
    #: each part's chosen capsules
    tried_m: tuple[float, ...]
    #: SHA-256 of the unique vertices (float32, little-endian, sorted) the fit was made to hold
    vertices_sha256: str = ""


class _BodyModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    radius: float = Field(gt=0)


class _LinkModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    source: str
    vertices: int = Field(ge=0)
    triangles: int = Field(ge=0)
    worst_over_approximation_m: float = Field(ge=0)
    tried_m: list[float]
    vertices_sha256: str = Field(pattern=r"^([0-9a-f]{64})?$")
    bodies: list[_BodyModel] = Field(min_length=1)


class _ExcludedModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    bodies: tuple[str, str]
    reason: Literal["apart", "overlapping", "adjacent"]
    proof: str


class _PairsModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    joint_limits: dict[str, tuple[float, float]]
    clearance_m: float = Field(ge=0)
    included: list[tuple[str, str]]
    excluded: list[_ExcludedModel]


class _FileModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    format: Literal["armwarden-fitted-geometry/1"]
    robot: str
    source: dict[str, str]
    margin_m: float = Field(ge=0)
    links: dict[str, _LinkModel]
    pairs: _PairsModel | None = None

    @field_validator("links")
    @classmethod
    def _names_match_links(cls, links: dict[str, _LinkModel]) -> dict[str, _LinkModel]:
        for link, entry in links.items():
            for body in entry.bodies:
                if not body.name.startswith(f"{link}/"):
                    raise ValueError(f"body {body.name!r} is listed under link {link!r}")
        return links


@dataclass(frozen=True)
class ExcludedPair:
    """A body pair left out of self-collision checks, and the proof that it may be."""

    bodies: tuple[str, str]
    reason: Literal["apart", "overlapping", "adjacent"]
    proof: str


@dataclass(frozen=True)
class FittedGeometry:
    """What a fitted-geometry file holds: capsules per link (link frame, metres) and the pair analysis."""

    robot: str
    source: Mapping[str, str]
    margin_m: float
    links: Mapping[str, LinkFit]
    joint_limits: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    #: excluded "apart" pairs stay at least this far apart (capsule surfaces) [m]
    pair_clearance_m: float = 0.0
    included_pairs: tuple[tuple[str, str], ...] = ()
    excluded_pairs: tuple[ExcludedPair, ...] = ()

    def bodies(self) -> dict[str, FittedBody]:
        """Every body by name, in file order."""
        return {body.name: body for fit in self.links.values() for body in fit.bodies}


def load_fitted(path: Path) -> FittedGeometry:
    """Read and validate a fitted-geometry file.

    The file is read every time; what it says is parsed once per distinct content (`_parse_fitted`):
    every robot model reads it (every daemon start, every Guard a test builds), and parsing the
    bundled ~4,000 lines costs 0.05-0.1 s even with libyaml, which made YAML most of the test
    suite's time. The result is immutable, so sharing it is safe."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise FittingError(f"cannot read fitted geometry {path}: {exc}") from exc
    return _parse_fitted(text, str(path))


@functools.lru_cache(maxsize=8)
def _parse_fitted(text: str, path: str) -> FittedGeometry:
    """The geometry `text` (the file at `path`) describes; a memo of a pure function of its arguments."""
    try:
        # libyaml's safe loader where PyYAML has it (0.05 s instead of 0.4 s for the bundled file)
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        raw = yaml.load(text, Loader=loader)  # a safe loader either way
        parsed = _FileModel.model_validate(raw)
    except (yaml.YAMLError, ValueError) as exc:
        raise FittingError(f"cannot read fitted geometry {path}: {exc}") from exc
    links = {
        name: LinkFit(
            link=name,
            source=entry.source,
            bodies=tuple(FittedBody(b.name, b.p0, b.p1, b.radius) for b in entry.bodies),
            n_vertices=entry.vertices,
            n_triangles=entry.triangles,
            worst_over_approximation_m=entry.worst_over_approximation_m,
            tried_m=tuple(entry.tried_m),
            vertices_sha256=entry.vertices_sha256,
        )
        for name, entry in parsed.links.items()
    }
    pairs = parsed.pairs
    return FittedGeometry(  # read-only mappings: one parse is shared by every model of this content
        robot=parsed.robot,
        source=MappingProxyType(dict(parsed.source)),
        margin_m=parsed.margin_m,
        links=MappingProxyType(links),
        joint_limits=MappingProxyType(dict(pairs.joint_limits) if pairs else {}),
        pair_clearance_m=pairs.clearance_m if pairs else 0.0,
        included_pairs=tuple(tuple(p) for p in pairs.included) if pairs else (),  # type: ignore[misc]
        excluded_pairs=tuple(ExcludedPair(e.bodies, e.reason, e.proof) for e in pairs.excluded) if pairs else (),
    )


def _num(value: float) -> str:
    text = repr(float(value))
    return "0.0" if text == "-0.0" else text


def _vec(values: Sequence[float]) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def render_fitted(geometry: FittedGeometry, header: Sequence[str]) -> str:
    """The data file's text: `header` as comment lines, then YAML in a fixed order (same input,
    same bytes)."""
    lines = [f"# {line}".rstrip() for line in header]
    lines += [f"format: {FORMAT}", f"robot: {geometry.robot}", "source:"]
    lines += [f"  {key}: {_quote(value)}" for key, value in geometry.source.items()]
    lines += [f"margin_m: {_num(geometry.margin_m)}", "links:"]
    for name, fit in geometry.links.items():
        lines += [
            f"  {name}:",
            f"    source: {_quote(fit.source)}",
            f"    vertices: {fit.n_vertices}",
            f"    triangles: {fit.n_triangles}",
            f"    worst_over_approximation_m: {_num(fit.worst_over_approximation_m)}",
            f"    tried_m: {_vec(fit.tried_m)}",
            f"    vertices_sha256: {_quote(fit.vertices_sha256)}",
            "    bodies:",
        ]
        lines += [
            f"      - {{name: {body.name}, p0: {_vec(body.p0_m)}, p1: {_vec(body.p1_m)}, radius: {_num(body.radius_m)}}}"
            for body in fit.bodies
        ]
    if geometry.joint_limits or geometry.included_pairs or geometry.excluded_pairs:
        lines += ["pairs:", "  joint_limits:"]
        lines += [f"    {joint}: {_vec(limits)}" for joint, limits in geometry.joint_limits.items()]
        lines += [f"  clearance_m: {_num(geometry.pair_clearance_m)}"]
        lines += ["  included:"] + [f"    - [{a}, {b}]" for a, b in geometry.included_pairs]
        if not geometry.included_pairs:
            lines[-1] = "  included: []"
        lines += ["  excluded:"]
        for pair in geometry.excluded_pairs:
            lines += [
                f"    - bodies: [{pair.bodies[0]}, {pair.bodies[1]}]",
                f"      reason: {pair.reason}",
                f"      proof: {_quote(pair.proof)}",
            ]
        if not geometry.excluded_pairs:
            lines[-1] = "  excluded: []"
    return "\n".join(lines) + "\n"


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'
