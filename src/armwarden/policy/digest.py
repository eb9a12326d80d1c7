"""The policy's digest: which policy was in force, as one short string the audit log can carry.

SHA-256 over the canonical JSON of the *validated* policy (keys sorted, no whitespace), so two
files that differ only in comments, key order or formatting digest alike, and any change to a
value the daemon enforces digests differently. A URDF named by path is covered by its path, not
its bytes.
"""

from __future__ import annotations

import hashlib
import json

from armwarden.policy.models import Policy

#: prefix of every digest, naming the hash (a later scheme would get another prefix)
DIGEST_PREFIX = "sha256:"


def policy_digest(policy: Policy) -> str:
    """``sha256:<hex>`` of the policy's canonical JSON."""
    document = policy.model_dump(mode="json")
    canonical = json.dumps(document, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return DIGEST_PREFIX + hashlib.sha256(canonical.encode("utf-8")).hexdigest()
