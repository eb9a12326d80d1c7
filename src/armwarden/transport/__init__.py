"""Transports and access control (design §5): bearer tokens and the streamable HTTP app.

`armwarden.transport.tokens` manages the hashed token file and authenticates presented tokens;
`armwarden.transport.http` builds the Starlette app (``/mcp`` + ``/healthz``) with Host/Origin
checks and bearer auth, serves it with uvicorn, and exposes the caller's `Principal` to tools
through `current_principal`. The HTTP names are imported lazily so that ``armwarden tokens ...``
and stdio serving do not import uvicorn/Starlette.
"""

from __future__ import annotations

import importlib
from typing import Any

from armwarden.transport.tokens import (
    Principal,
    Role,
    TokenInfo,
    TokenStore,
    tokens_add_command,
    tokens_list_command,
    tokens_revoke_command,
)

_HTTP_NAMES = frozenset(
    {"build_http_app", "check_bind_safety", "current_principal", "is_loopback_host", "role_allows", "serve_http"}
)

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
    if name in _HTTP_NAMES:
        return getattr(importlib.import_module("armwarden.transport.http"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
