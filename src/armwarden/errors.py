"""One error hierarchy for the whole daemon, split by phase.

```
ArmWardenError
├── ConfigurationError        bad policy / backend config / CLI arguments (exit 2 at start-up)
│   └── PolicyError           the safety policy failed validation (carries every error with its path)
├── BackendUnavailable        the chosen backend cannot be imported or opened (exit 2 at start-up)
├── BackendError              a backend operation failed while running
│   └── BackendTimeout        a backend operation did not answer in time (also a TimeoutError)
├── RobotModelError           the robot description cannot be loaded or a frame is unknown
└── SafetyRefusal             the Guard refused a request (becomes an `isError` tool result)
```
Messages carry the facts (joint, value, limit, valid names) so that a human reading
the audit log or a tool result knows what happened and what to do.
"""

from __future__ import annotations

from collections.abc import Sequence


class ArmWardenError(Exception):
    """Root of every error ArmWarden raises on purpose."""


class ConfigurationError(ArmWardenError):
    """Configuration that cannot be used; the daemon refuses to start."""


class PolicyError(ConfigurationError):
    """The safety policy is invalid. `errors` holds one `(yaml_path, message)` per problem."""

    def __init__(self, source: str, errors: Sequence[tuple[str, str]]) -> None:
        self.source = source
        self.errors = list(errors)
        lines = "\n".join(f"  {path}: {message}" for path, message in self.errors)
        super().__init__(f"invalid policy {source}:\n{lines}")


class RobotModelError(ArmWardenError):
    """The robot description could not be loaded, or a frame/joint name is unknown."""


class BackendUnavailable(ArmWardenError):
    """The requested backend cannot be used here (missing dependency, device absent)."""


class BackendError(ArmWardenError):
    """A backend operation failed while the daemon was running."""


class BackendTimeout(BackendError, TimeoutError):
    """A backend operation did not complete within its deadline (also a `TimeoutError`, so code
    that bounds a call with its own deadline treats both alike)."""


class SafetyRefusal(ArmWardenError):
    """The Guard refused a request. `code` is stable and machine-readable; the message is for humans."""

    def __init__(self, code: str, message: str) -> None:
        self.code = code
        super().__init__(message)
