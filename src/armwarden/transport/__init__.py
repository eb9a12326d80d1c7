"""Transports and access control (docs/architecture.md, "Transports and access").

- `tokens`: the hashed token file; authenticates presented tokens.
- `access`: the caller's `Principal` inside a tool (`current_principal`) and what a role may call.
- `http`: the Starlette app (``/mcp`` + ``/healthz``) with Host/Origin checks, served with
  uvicorn; `bearer` authenticates its bearer tokens; `abandoned` cancels the motion call of an
  HTTP client that went away.
- `stdio`: MCP on stdin/stdout, with parse errors answered and open request ids kept unique.
- `jsonrpc`: error codes and the request-id rule both transports share.

Names are imported on first use, so ``armwarden tokens ...`` does not import the MCP SDK and
serving on stdio imports none of ArmWarden's HTTP modules.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from armwarden.transport.token_storage import Role
from armwarden.transport.tokens import (
    Principal,
    TokenInfo,
    TokenStore,
    tokens_add_command,
    tokens_list_command,
    tokens_revoke_command,
)

if TYPE_CHECKING:  # for type checkers only; at run time these come from __getattr__ below
    from armwarden.transport.access import current_principal, role_allows
    from armwarden.transport.http import build_http_app, check_bind_safety, is_loopback_host, serve_http

#: names imported on first use, from the module that defines them
_LAZY = {
    "build_http_app": "armwarden.transport.http",
    "check_bind_safety": "armwarden.transport.http",
    "is_loopback_host": "armwarden.transport.http",
    "serve_http": "armwarden.transport.http",
    "current_principal": "armwarden.transport.access",
    "role_allows": "armwarden.transport.access",
}

__all__ = [
    "Principal",
    "Role",
    "TokenInfo",
    "TokenStore",
    "build_http_app",
    "check_bind_safety",
    "current_principal",
    "is_loopback_host",
    "role_allows",
    "serve_http",
    "tokens_add_command",
    "tokens_list_command",
    "tokens_revoke_command",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
