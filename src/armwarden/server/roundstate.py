"""The `request_state` of an out-of-band approval round under protocol 2026-07-28, sealed so the
client can carry it but neither forge nor alter it.

Why our own seal when the SDK already seals every `request_state`: the SDK's seal is a transport
matter (its key, its expiry, configurable per deployment); ours binds the round to this daemon's
approval board whatever the transport does. The token is ``aw1.<claims>.<mac>``: the claims as
compact JSON (base64url) and an HMAC-SHA256 over them with a secret made when the daemon starts
(so a restart voids every round in flight). It authenticates; it is not secret (the claims name a
plan and a request, which the client knows). One-time use is the board's job
(`PendingApprovals.start_round` / `spend_round`), not the token's.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
from dataclasses import asdict, dataclass

__all__ = ["RoundClaims", "RoundSeal"]

PREFIX = "aw1."
#: longest token `open` looks at (claims are a few hundred bytes)
MAX_TOKEN_CHARS = 2048


@dataclass(frozen=True)
class RoundClaims:
    """What one approval round was about: the plan and the board's request, the round's one-time
    nonce, and the channel it was asked on (`url` or `both`)."""

    plan_id: str
    request_id: str
    digest: str
    nonce: str
    channel: str


class RoundSeal:
    """Seals and opens round claims with a per-instance secret (one per daemon)."""

    def __init__(self, secret: bytes | None = None) -> None:
        self._secret = secret if secret is not None else secrets.token_bytes(32)

    def seal(self, claims: RoundClaims) -> str:
        body = PREFIX + _b64(json.dumps(asdict(claims), separators=(",", ":"), sort_keys=True).encode())
        return f"{body}.{_b64(self._mac(body))}"

    def open(self, token: object) -> RoundClaims | None:
        """The claims of a token this seal made, unaltered; None for anything else."""
        if not isinstance(token, str) or len(token) > MAX_TOKEN_CHARS or not token.startswith(PREFIX):
            return None
        body, _, mac = token.rpartition(".")
        # compared as text: base64 decoding ignores stray low bits, so two spellings could decode alike
        if not hmac.compare_digest(mac, _b64(self._mac(body))):
            return None
        try:
            fields = json.loads(_unb64(body[len(PREFIX):]))
            return RoundClaims(**{name: str(fields[name]) for name in RoundClaims.__dataclass_fields__})
        except (ValueError, KeyError, TypeError):
            return None

    def _mac(self, body: str) -> bytes:
        return hmac.new(self._secret, body.encode(), hashlib.sha256).digest()


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).decode().rstrip("=")


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))
