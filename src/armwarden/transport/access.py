"""Who is calling, and which tools their role may call; shared by every transport.

Lean on purpose (no Starlette app, no uvicorn): the tool layer imports it on stdio too, where there
is never a principal. The HTTP transport (`http.py`) authenticates bearer tokens and publishes the
principal to the SDK; `current_principal` reads it back inside a tool.
"""

from __future__ import annotations

from mcp.server.auth.middleware.auth_context import get_access_token

from armwarden.tools import spec_of
from armwarden.transport.token_storage import ROLES
from armwarden.transport.tokens import Principal

__all__ = ["current_principal", "role_allows"]


def role_allows(role: str, tool: str) -> bool:
    """May `role` call `tool`?

    operator and agent: every tool (the policy decides which exist; an agent's token only cannot
    sign in to the operator console). observer: the tools whose record says so
    (`ToolSpec.observer_may_call`: the introspect and perception groups, and stopping the robot and
    reading the safety status). Unknown roles and, for observers, unknown tools are refused.
    """
    if role in ("operator", "agent"):
        return True
    if role == "observer":
        spec = spec_of(tool)
        return spec is not None and spec.observer_may_call
    return False


def current_principal() -> Principal | None:
    """The principal of the HTTP request being served, or None (stdio, or HTTP without tokens).

    Call it inside a tool (or anything the tool awaits); it works under 2025-11-25 and
    2026-07-28 because the SDK propagates the request's context into the tool's task.
    """
    access = get_access_token()
    if access is None:
        return None
    role = (access.claims or {}).get("armwarden_role")
    if role not in ROLES:  # a token not minted by BearerAuth (e.g. an SDK verifier): no role
        return None
    return Principal(name=access.client_id, role=role)
