"""Errors of the CAN layer: a frame that cannot be what it claims, a model nobody configured.

`InvalidFrame` is the one exception every parser raises for a malformed frame (wrong length,
wrong type, wrong host, a field out of its encoding): a caller counts it as an INVALID_FRAME
health event and goes on reading; any other exception from a parser is a bug.
"""

from __future__ import annotations

from armwarden.core.errors import BackendError, ConfigurationError


class InvalidFrame(BackendError):
    """A received CAN frame is malformed or not the frame the parser was asked to read."""


class UnknownModel(ConfigurationError):
    """An actuator model name has no value ranges; the message lists the known ones."""


__all__ = ["InvalidFrame", "UnknownModel"]
