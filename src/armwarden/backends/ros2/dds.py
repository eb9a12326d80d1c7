"""Which DDS domain and discovery range a ROS node of ours uses, and how to say so (no rclpy).

The daemon's ros2 backend and the fake cell (`armwarden.backends.ros2.fake_cell`) resolve them here, so that both,
started with nothing set (a desktop client's minimal environment), meet: ``ROS_DOMAIN_ID`` unset
is domain 0, as ROS itself has it, and ``ROS_AUTOMATIC_DISCOVERY_RANGE`` unset is ``LOCALHOST``
(ROS's own default is ``SUBNET``): DDS leaves this host only when that is asked for.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass

from armwarden.core.errors import BackendError

DOMAIN_ENV = "ROS_DOMAIN_ID"
RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
#: ROS's own default domain
DEFAULT_DOMAIN_ID = 0
#: ours: DDS stays on this host unless the environment widens it
DEFAULT_DISCOVERY_RANGE = "LOCALHOST"
#: the values rcl accepts (SYSTEM_DEFAULT is the RMW's own, SUBNET in Jazzy)
DISCOVERY_RANGES = ("OFF", "LOCALHOST", "SUBNET", "SYSTEM_DEFAULT")
#: the largest domain id DDS allows on Linux
MAX_DOMAIN_ID = 232


@dataclass(frozen=True)
class DdsSettings:
    """A domain and a discovery range, and where each came from (for messages)."""

    domain_id: int
    domain_from: str  # "ROS_DOMAIN_ID", "domain_id in the backend config" or "default"
    discovery_range: str
    range_from: str  # "ROS_AUTOMATIC_DISCOVERY_RANGE" or "default"

    def describe(self) -> str:
        """E.g. ``ROS_DOMAIN_ID=0 (unset: the default), ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (...)``."""
        domain = {"default": " (unset: the default)", DOMAIN_ENV: ""}.get(self.domain_from, f" ({self.domain_from})")
        scope = " (unset: the default)" if self.range_from == "default" else ""
        return f"{DOMAIN_ENV}={self.domain_id}{domain}, {RANGE_ENV}={self.discovery_range}{scope}"

    def how_to_agree(self) -> str:
        """What to do when the other side is not heard: the same domain and a range that reaches it."""
        return (f"the publisher must run with the same {DOMAIN_ENV} and a discovery range that reaches this "
                f"node (both LOCALHOST on one host, SUBNET across hosts): export both before starting the "
                f"daemon (a desktop client passes only what its config's \"env\" names) and the cell")

    def apply(self, environ: MutableMapping[str, str] = os.environ) -> None:
        """Put the default discovery range into `environ` when it is unset there: rcl reads the
        range only from the environment (rclpy has no option for it), at init."""
        if self.range_from == "default":
            environ[RANGE_ENV] = self.discovery_range


def dds_settings(config_domain: int | None = None, environ: Mapping[str, str] = os.environ) -> DdsSettings:
    """The domain (the backend config's, else ``ROS_DOMAIN_ID``, else 0) and the discovery range
    (``ROS_AUTOMATIC_DISCOVERY_RANGE``, else ``LOCALHOST``); a malformed value is a `BackendError`."""
    if config_domain is not None:
        domain, domain_from = config_domain, "domain_id in the backend config"
    else:
        text = environ.get(DOMAIN_ENV, "").strip()
        if not text:
            domain, domain_from = DEFAULT_DOMAIN_ID, "default"
        else:
            try:
                domain = int(text)
            except ValueError:
                raise BackendError(f"{DOMAIN_ENV}={text!r} is not a number") from None
            domain_from = DOMAIN_ENV
    if not 0 <= domain <= MAX_DOMAIN_ID:
        raise BackendError(f"{DOMAIN_ENV}={domain} is outside 0..{MAX_DOMAIN_ID}")
    scope = environ.get(RANGE_ENV, "").strip()
    if not scope:
        return DdsSettings(domain, domain_from, DEFAULT_DISCOVERY_RANGE, "default")
    if scope not in DISCOVERY_RANGES:
        raise BackendError(f"{RANGE_ENV}={scope!r} is not one of {', '.join(DISCOVERY_RANGES)}")
    return DdsSettings(domain, domain_from, scope, RANGE_ENV)


__all__ = ["DEFAULT_DISCOVERY_RANGE", "DEFAULT_DOMAIN_ID", "DdsSettings", "dds_settings"]
