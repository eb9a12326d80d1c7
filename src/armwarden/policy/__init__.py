"""The safety policy: a strict, versioned, immutable description of everything the daemon allows.

The policy is the one input the server trusts (the model is not), so it is validated harder than
anything else:

* every mapping rejects unknown keys (a typo must never silently fall back to a default);
* scalars are strictly typed (``true`` is not ``1.0``, ``"0.3"`` is not ``0.3``) and floats must
  be finite (``.nan`` / ``.inf`` are errors);
* every number that could switch a protection off is bounded (a force limit of 10 kN, a start
  tolerance of 10 rad or a force monitor slower than its own staleness timeout is refused, not
  accepted and not clamped);
* sequences become tuples and mappings become read-only, so the loaded policy cannot be changed
  for the life of the process;
* duplicate YAML keys are errors (PyYAML would silently keep the last one);
* cross-field rules (limits cover the joints, home within limits, defaults within caps, ...) are
  small named functions, each returning the violations it found;
* every problem is reported at once, each with the YAML path of the offending value, as a
  :class:`~armwarden.core.errors.PolicyError`.

Units are SI throughout: metres, radians, seconds, newtons; positions in the robot base frame.

Modules: `constants` (tool groups, approvable actions), `fields` (strict field types and the
rule plumbing), one module per group of sections (`robot`, `workspace`, `motion`, `devices`,
`access`), `models` (the `Policy` root), `loading` (files, YAML, `bundled_policy`), `messages`
(errors at their YAML paths), `digest` (the digest the audit log records) and `summary` (what `armwarden check-policy` prints).
"""

from __future__ import annotations

from armwarden.policy.access import ApprovalConfig, RateLimitsConfig, ToolsConfig
from armwarden.policy.constants import (
    ALL_TOOLS,
    APPROVAL_ACTIONS,
    DOCUMENT_PATH,
    MAX_POLICY_BYTES,
    RATE_LIMIT_EXEMPT_TOOLS,
    TOOL_GROUPS,
)
from armwarden.policy.devices import ControllersConfig, GripperConfig, PerceptionConfig
from armwarden.policy.digest import policy_digest
from armwarden.policy.fields import FrozenMap
from armwarden.policy.joint_torques import JointTorqueConfig
from armwarden.policy.loading import apply_overrides, bundled_policy, load_policy, parse_policy
from armwarden.policy.messages import format_path, validation_errors
from armwarden.policy.models import Policy
from armwarden.policy.motion import ForceConfig, MotionConfig
from armwarden.policy.robot import JointLimits, RobotConfig
from armwarden.policy.summary import policy_json_schema, summarize_policy
from armwarden.policy.workspace import Box, KeepOutZone, WorkspaceConfig

__all__ = [
    "ALL_TOOLS",
    "APPROVAL_ACTIONS",
    "DOCUMENT_PATH",
    "MAX_POLICY_BYTES",
    "RATE_LIMIT_EXEMPT_TOOLS",
    "TOOL_GROUPS",
    "ApprovalConfig",
    "Box",
    "ControllersConfig",
    "ForceConfig",
    "FrozenMap",
    "GripperConfig",
    "JointLimits",
    "JointTorqueConfig",
    "KeepOutZone",
    "MotionConfig",
    "PerceptionConfig",
    "Policy",
    "RateLimitsConfig",
    "RobotConfig",
    "ToolsConfig",
    "WorkspaceConfig",
    "apply_overrides",
    "bundled_policy",
    "format_path",
    "load_policy",
    "parse_policy",
    "policy_digest",
    "policy_json_schema",
    "summarize_policy",
    "validation_errors",
]
