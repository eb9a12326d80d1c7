"""The `workspace` section: the box the arm must stay in and the keep-out zones it must avoid."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Annotated

from pydantic import AfterValidator, BaseModel, Field, WrapSerializer, model_validator

from armwarden.policy.fields import (
    MODEL_CONFIG,
    FrozenMap,
    Name,
    StrictBool,
    UniqueNames,
    Vector3,
    Violation,
    boxes_overlap,
    check_min_below_max,
    enforce,
    finite,
    freeze_map,
    not_empty,
    serialize_map,
)

#: the largest padding a link may be given [m]: more is a unit mistake (millimetres typed as metres)
MAX_PADDING_M = 0.5
Padding = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0, le=MAX_PADDING_M)]


class Box(BaseModel):
    """An axis-aligned box in the robot base frame."""

    model_config = MODEL_CONFIG

    min: Vector3 = Field(description="Lower corner [x, y, z] in metres, base frame; each within ±5 m.")
    max: Vector3 = Field(description="Upper corner [x, y, z] in metres, base frame; each within ±5 m.")

    @model_validator(mode="after")
    def _rules(self) -> Box:
        enforce([check_min_below_max(self.min, self.max)])
        return self


class KeepOutZone(BaseModel):
    """A named box no part of the arm (TCP or padded link geometry) may enter."""

    model_config = MODEL_CONFIG

    name: Name = Field(description="Zone name (no unit), unique, quoted in violations.")
    min: Vector3 = Field(description="Lower corner [x, y, z] in metres, base frame; each within ±5 m.")
    max: Vector3 = Field(description="Upper corner [x, y, z] in metres, base frame; each within ±5 m.")

    @model_validator(mode="after")
    def _rules(self) -> KeepOutZone:
        enforce([check_min_below_max(self.min, self.max)])
        return self


class WorkspaceConfig(BaseModel):
    """Where the arm may be: inside `box`, outside every `keep_out` zone, links padded.

    Padding: every collision body of a link is grown by `link_padding_m`, or by that link's entry
    in `padding_by_link_m`, for the workspace and keep-out checks (self-collision compares the
    bodies unpadded: they already hold the manufacturer's meshes with a margin). The bundled FR3
    policy pads the arm links and the hand by 1 cm and the fingers by 2 mm: a top-down grasp puts
    the fingertips about 4 mm above the table with the TCP 2 cm above it, and the fingers' capsules
    hold Franka's finger collision boxes at every opening width with at least 1 mm to spare."""

    model_config = MODEL_CONFIG

    box: Box = Field(description="Workspace box (metres, base frame) the TCP and every checked link must stay in.")
    keep_out: tuple[KeepOutZone, ...] = Field(
        default=(), description="Keep-out boxes (metres, base frame) the TCP and every checked link must avoid."
    )
    link_padding_m: float = finite(
        ge=0, default=0.01, description="Padding [m] added to every link's collision geometry."
    )
    padding_by_link_m: Annotated[
        Mapping[Name, Padding], AfterValidator(freeze_map), WrapSerializer(serialize_map)
    ] = Field(
        default_factory=FrozenMap,
        description="Padding [m] per link that replaces `link_padding_m` for that link's collision bodies (e.g. "
        "less on the fingers, which must come close to the table for a grasp); each in [0, 0.5]. A name that is "
        "not a link of the robot is refused at start-up.",
    )
    check_links: Annotated[UniqueNames, AfterValidator(not_empty)] | None = Field(
        default=None,
        description="Links (no unit) whose collision geometry is checked; null (the default) means every link "
        "that moves. A list must name every link that moves with a driven joint and carries collision geometry "
        "(links fixed to the base may be added; they cannot move into anything): check-policy and serve refuse "
        "one that leaves such a link out, naming it, since the workspace, keep-out and self-collision checks "
        "would silently skip it. There is no opt-out. An empty list is an error: it would check no link at all.",
    )
    self_collision: StrictBool = Field(default=True, description="Check links against each other (boolean).")

    @model_validator(mode="after")
    def _rules(self) -> WorkspaceConfig:
        enforce([self._keep_out_names_unique(), self._keep_out_zones_overlap_the_box()])
        return self

    def _keep_out_zones_overlap_the_box(self) -> Iterator[Violation]:
        """A zone entirely outside the workspace box protects nothing (usually a wrong sign, frame or unit)."""
        for index, zone in enumerate(self.keep_out):
            if not boxes_overlap(zone.min, zone.max, self.box.min, self.box.max):
                yield ("keep_out", index), (
                    f"keep-out zone {zone.name!r} lies entirely outside the workspace box, so it would protect "
                    "nothing; check its coordinates (metres, base frame)"
                )

    def _keep_out_names_unique(self) -> Iterator[Violation]:
        """Violations quote the zone name; two zones with one name would make reports ambiguous."""
        first: dict[str, int] = {}
        for index, zone in enumerate(self.keep_out):
            if zone.name in first:
                yield ("keep_out", index, "name"), (
                    f"duplicate keep-out name {zone.name!r} (already used by keep_out[{first[zone.name]}])"
                )
            else:
                first[zone.name] = index

