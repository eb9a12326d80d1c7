"""One error hierarchy for the whole daemon, split by phase.

```
ArmWardenError
├── ConfigurationError        bad policy / backend config / CLI arguments (exit 2 at start-up)
│   └── PolicyError           the safety policy failed validation (carries every error with its path)
├── BackendUnavailable        the chosen backend cannot be imported or opened (exit 2 at start-up)
├── BackendError              a backend operation failed while running
│   └── BackendTimeout        a backend operation did not answer in time (also a TimeoutError)
├── RobotModelError           the robot description cannot be loaded or a frame is unknown
└── SafetyRefusal             the Guard refused a request (becomes an `isError` tool result);
                              its `code` is a `RefusalCode`
```
Messages carry the facts (joint, value, limit, valid names) so that a human reading
the audit log or a tool result knows what happened and what to do.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

if sys.version_info >= (3, 11):
    from enum import StrEnum
else:  # Python 3.10 (still supported): a str enum whose str() is its value, as 3.11's StrEnum
    from enum import Enum

    class StrEnum(str, Enum):
        def __str__(self) -> str:
            return str(self.value)


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


class StoppedBeforeStart(BackendError):
    """An actuation decided before a stop reached the backend after it: nothing was started."""


class RefusalCode(StrEnum):
    """Every reason the server refuses a call. The value is what clients see (`REFUSED [CODE]`, the
    audit record's `code`); values never change, new reasons get new members."""

    # admission and state
    RATE_LIMITED = "RATE_LIMITED"
    ESTOPPED = "ESTOPPED"
    NOT_ESTOPPED = "NOT_ESTOPPED"
    RESET_REFUSED = "RESET_REFUSED"
    AUDIT_UNAVAILABLE = "AUDIT_UNAVAILABLE"
    BUSY = "BUSY"
    NO_STATE = "NO_STATE"
    STALE_STATE = "STALE_STATE"
    FORBIDDEN = "FORBIDDEN"
    # arguments
    INVALID = "INVALID"
    INVALID_ARGUMENTS = "INVALID_ARGUMENTS"
    OUT_OF_RANGE = "OUT_OF_RANGE"
    NOT_ALLOWED = "NOT_ALLOWED"
    NOT_CONFIGURED = "NOT_CONFIGURED"
    UNKNOWN_FRAME = "UNKNOWN_FRAME"
    IMAGE_TOO_WIDE = "IMAGE_TOO_WIDE"
    # plans
    UNKNOWN_PLAN = "UNKNOWN_PLAN"
    EXPIRED_PLAN = "EXPIRED_PLAN"
    USED_PLAN = "USED_PLAN"
    REJECTED_PLAN = "REJECTED_PLAN"
    STALE_PLAN = "STALE_PLAN"
    INVALIDATED_PLAN = "INVALIDATED_PLAN"
    NOT_PLAN_OWNER = "NOT_PLAN_OWNER"
    ENVELOPE = "ENVELOPE"
    # approval
    APPROVAL_UNAVAILABLE = "APPROVAL_UNAVAILABLE"
    APPROVAL_DENIED = "APPROVAL_DENIED"
    APPROVAL_INVALID = "APPROVAL_INVALID"
    APPROVAL_MISMATCH = "APPROVAL_MISMATCH"
    # force and motion
    NO_WRENCH = "NO_WRENCH"
    IN_CONTACT = "IN_CONTACT"
    FORCE_LIMIT = "FORCE_LIMIT"
    STOPPED = "STOPPED"
    STOP_FAILED = "STOP_FAILED"
    # backend and server
    BACKEND_ERROR = "BACKEND_ERROR"
    BACKEND_FAULT = "BACKEND_FAULT"
    INTERNAL_ERROR = "INTERNAL_ERROR"


class SafetyRefusal(ArmWardenError):
    """The server refused a request. `code` is stable and machine-readable; the message is for humans.
    A code that is not a `RefusalCode` is a programming error (ValueError), never a new wire value."""

    def __init__(self, code: RefusalCode | str, message: str) -> None:
        self.code = RefusalCode(code)
        super().__init__(message)
