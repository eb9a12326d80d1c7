"""Bearer-token authentication for the HTTP transport: who is calling, before any route runs.

`BearerAuth` turns ``Authorization: Bearer <token>`` into the SDK's `AuthenticatedUser`/`AccessToken`
(``client_id`` = token name, ``subject`` = a fingerprint of the token, ``scopes`` = [role]), so the
SDK binds sessions and sealed ``requestState`` to that very token and `current_principal` reads it
back inside a tool. The Authorization header is removed before the request reaches the SDK, so
``ctx.headers`` never carries the token. A refusal is a 401 with ``WWW-Authenticate``; on a
reported path it is first handed to `on_refused` (the shared refusal limiter and the audit log).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Iterable, Sequence

from mcp.server.auth.middleware.auth_context import AuthContextMiddleware
from mcp.server.auth.middleware.bearer_auth import AuthenticatedUser
from mcp.server.auth.provider import AccessToken
from starlette.datastructures import Headers
from starlette.responses import JSONResponse, Response
from starlette.types import ASGIApp, Receive, Scope, Send

from armwarden.transport.jsonrpc import RefusedCallback, RefusedRequest
from armwarden.transport.tokens import TokenStore

__all__ = ["BearerAuth"]

logger = logging.getLogger(__name__)


def _unauthorized(description: str, *, invalid: bool) -> Response:
    challenge = 'Bearer realm="armwarden"' + (', error="invalid_token"' if invalid else "")
    return JSONResponse(
        {"error": "invalid_token" if invalid else "unauthorized", "error_description": description},
        status_code=401,
        headers={"WWW-Authenticate": challenge},
    )


class BearerAuth:
    """Pure ASGI: require a valid bearer token on every path but `public_paths`."""

    def __init__(self, app: ASGIApp, token_store: TokenStore, own_auth_prefixes: Sequence[str] = (),
                 on_refused: RefusedCallback | None = None, reported_paths: Sequence[str] = (),
                 public_paths: Iterable[str] = ()) -> None:
        self.app = AuthContextMiddleware(app)  # SDK: scope["user"] -> get_access_token()
        self.token_store = token_store
        #: paths served without a token (Host/Origin are checked before this, on every path)
        self.public_paths = frozenset(public_paths)
        #: a refusal on one of `reported_paths` is handed to `on_refused` before its 401
        self.on_refused = on_refused
        self.reported_paths = frozenset(reported_paths)
        #: path prefixes that authenticate by themselves (the operator console's session cookie)
        self.own_auth_prefixes = tuple(own_auth_prefixes)

    def _own_auth(self, path: str) -> bool:
        return any(path == prefix or path.startswith(prefix + "/") for prefix in self.own_auth_prefixes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] in self.public_paths or self._own_auth(scope["path"]):
            await self.app(scope, receive, send)
            return
        values = Headers(scope=scope).getlist("authorization")
        client = (scope.get("client") or ("?", 0))[0]
        if not values:
            await self._report(scope, client, "no bearer token")
            await _unauthorized("this server requires 'Authorization: Bearer <token>'", invalid=False)(
                scope, receive, send
            )
            return
        scheme, _, presented = values[0].partition(" ")
        principal = None
        if len(values) == 1 and scheme.lower() == "bearer":
            principal = self.token_store.authenticate(presented.strip())
        if principal is None:
            logger.warning("rejected HTTP request from %s: invalid bearer token", client)
            await self._report(scope, client, "the bearer token is not valid")
            await _unauthorized("the bearer token is not valid (unknown or revoked)", invalid=True)(
                scope, receive, send
            )
            return
        scope = dict(scope)
        scope["headers"] = [(k, v) for k, v in scope["headers"] if k.lower() != b"authorization"]
        scope["user"] = AuthenticatedUser(
            AccessToken(
                token=f"redacted:{principal.name}",  # never the token itself
                client_id=principal.name,
                # the SDK binds sessions and sealed request state to (client_id, issuer, subject):
                # a fingerprint of this very token, so a new token under a revoked token's name
                # cannot take over that token's sessions or pending questions
                subject=hashlib.sha256(presented.strip().encode("utf-8")).hexdigest()[:32],
                scopes=[principal.role],
                claims={"armwarden_role": principal.role},
            )
        )
        await self.app(scope, receive, send)

    async def _report(self, scope: Scope, client: str, why: str) -> None:
        """Hand a refusal on a reported path to `on_refused` (it thins floods and records)."""
        path = scope["path"]
        if self.on_refused is None or path not in self.reported_paths:
            return
        try:
            await self.on_refused(RefusedRequest(method=f"{scope.get('method', 'GET')} {path}", params=None,
                                                 request_id=None, outcome="refused", why=f"{path} refused (401): {why}",
                                                 peer=client))
        except Exception:  # the 401 is answered whatever the record did
            logger.exception("recording a refused request for %s failed", path)
