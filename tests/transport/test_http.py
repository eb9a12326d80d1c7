"""HTTP transport against a real uvicorn on 127.0.0.1:<free port>, driven by the SDK client."""

from __future__ import annotations

import contextlib
import functools
import socket
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import anyio
import anyio.from_thread
import anyio.lowlevel
import httpx2
import pytest
from mcp import Client
from mcp.client.streamable_http import streamable_http_client
from mcp.server.mcpserver import Context, Elicit, ElicitationResult, MCPServer, Resolve
from mcp_types import CallToolResult, ElicitResult, TextContent
from pydantic import BaseModel

from armwarden.core.errors import ConfigurationError
from armwarden.tools import spec_of
from armwarden.transport.access import current_principal, role_allows
from armwarden.transport.http import build_http_app, check_bind_safety, serve_http
from armwarden.transport.tokens import TokenStore
from tests.helpers import free_port

PROTOCOL_MODES = {"legacy": "2025-11-25", "2026-07-28": "2026-07-28"}
INIT_BODY = {
    "jsonrpc": "2.0",
    "id": 1,
    "method": "initialize",
    "params": {"protocolVersion": "2025-11-25", "capabilities": {}, "clientInfo": {"name": "t", "version": "0"}},
}
MCP_HEADERS = {"Accept": "application/json, text/event-stream", "Content-Type": "application/json"}


class Approval(BaseModel):
    approve: bool


def ask_approval() -> Elicit[Approval]:
    return Elicit("Approve?", Approval)


def make_server() -> MCPServer:
    """A tiny MCPServer: one observer-safe tool, one motion tool gated by `role_allows`, and one
    tool that asks the human (elicitation needs the stateful session under 2025-11-25)."""
    server = MCPServer("armwarden-test")

    async def read_thing(ctx: Context) -> dict[str, Any]:
        """Report who is calling."""
        await anyio.lowlevel.checkpoint()  # the principal must survive an await
        principal = current_principal()
        return {
            "name": principal.name if principal else None,
            "role": principal.role if principal else None,
            "protocol": ctx.protocol_version,
            "authorization_visible": "authorization" in (ctx.headers or {}),
        }

    async def move_thing(x: float) -> CallToolResult:
        """Pretend to move."""
        principal = current_principal()
        if principal is None or not role_allows(principal.role, "move_thing"):
            refusal = TextContent(type="text", text="refused: operator role required")
            return CallToolResult(content=[refusal], is_error=True)
        return CallToolResult(content=[TextContent(type="text", text=f"moved to {x} by {principal.name}")])

    async def approve_thing(approval: Annotated[ElicitationResult[Approval], Resolve(ask_approval)]) -> str:
        """Ask the human."""
        return f"{approval.action} by {current_principal()}"

    server.add_tool(read_thing)
    server.add_tool(move_thing)
    server.add_tool(approve_thing)
    return server


@contextlib.contextmanager
def running_server(app: Any, port: int) -> Iterator[None]:
    """Serve `app` with `serve_http` in a portal thread; set `shutdown` and join on exit."""
    with anyio.from_thread.start_blocking_portal() as portal:
        ready = portal.call(anyio.Event)
        shutdown = portal.call(anyio.Event)
        serving = portal.start_task_soon(
            functools.partial(serve_http, app, "127.0.0.1", port, ready=ready, shutdown=shutdown)
        )

        async def wait_ready() -> None:
            with anyio.fail_after(10):
                await ready.wait()

        portal.call(wait_ready)
        try:
            yield
        finally:
            portal.call(shutdown.set)
            serving.result(timeout=10)


@dataclass
class Served:
    url: str
    port: int
    token_path: Path
    operator: str
    observer: str

    @property
    def mcp(self) -> str:
        return self.url + "/mcp"


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    token_path = tmp_path_factory.mktemp("http") / "tokens.json"
    operator = TokenStore.add(token_path, "operator", name="alice")
    observer = TokenStore.add(token_path, "observer", name="bob")
    port = free_port()
    app = build_http_app(
        make_server(),
        host="127.0.0.1",
        port=port,
        token_store=TokenStore.load(token_path),
        health=lambda: {"status": "ok", "estop_latched": False},
    )
    with running_server(app, port):
        yield Served(f"http://127.0.0.1:{port}", port, token_path, operator, observer)


async def accept(context: Any, params: Any) -> ElicitResult:
    return ElicitResult(action="accept", content={"approve": True})


@contextlib.asynccontextmanager
async def mcp_client(url: str, token: str | None, mode: str):
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    async with httpx2.AsyncClient(headers=headers) as http, Client(
        streamable_http_client(url, http_client=http), mode=mode, elicitation_callback=accept
    ) as client:
        yield client


def post_initialize(served: Served, **headers: str) -> httpx2.Response:
    with httpx2.Client() as http:
        return http.post(served.mcp, json=INIT_BODY, headers={**MCP_HEADERS, **headers})


# ------------------------------------------------------------------------ authentication
def test_request_without_token_is_401_with_bearer_challenge(served: Served) -> None:
    response = post_initialize(served)

    assert response.status_code == 401
    assert response.headers["www-authenticate"].startswith("Bearer")
    assert response.json()["error"] == "unauthorized"


def test_request_with_wrong_token_is_401(served: Served) -> None:
    response = post_initialize(served, Authorization="Bearer aw_not-a-real-token")

    assert response.status_code == 401
    assert response.headers["www-authenticate"].startswith("Bearer")
    assert response.json()["error"] == "invalid_token"


def test_request_with_non_bearer_scheme_is_401(served: Served) -> None:
    response = post_initialize(served, Authorization=f"Basic {served.operator}")

    assert response.status_code == 401


def test_revoked_token_is_401_without_restart(served: Served) -> None:
    token = TokenStore.add(served.token_path, "operator", name="temp")
    assert post_initialize(served, Authorization=f"Bearer {token}").status_code == 200

    TokenStore.revoke(served.token_path, "temp")

    assert post_initialize(served, Authorization=f"Bearer {token}").status_code == 401


def test_session_cannot_be_used_with_another_token(served: Served) -> None:
    opened = post_initialize(served, Authorization=f"Bearer {served.operator}")
    session_id = opened.headers["mcp-session-id"]

    with httpx2.Client() as http:
        hijack = http.post(
            served.mcp,
            json={"jsonrpc": "2.0", "id": 2, "method": "tools/list"},
            headers={**MCP_HEADERS, "Authorization": f"Bearer {served.observer}", "mcp-session-id": session_id},
        )

    assert hijack.status_code == 404


@pytest.mark.anyio
@pytest.mark.parametrize("mode", PROTOCOL_MODES)
async def test_tool_sees_operator_principal(served: Served, mode: str) -> None:
    async with mcp_client(served.mcp, served.operator, mode) as client:
        result = await client.call_tool("read_thing", {})

    assert not result.is_error
    assert result.structured_content == {
        "name": "alice",
        "role": "operator",
        "protocol": PROTOCOL_MODES[mode],
        "authorization_visible": False,
    }


@pytest.mark.anyio
@pytest.mark.parametrize("mode", PROTOCOL_MODES)
async def test_tool_sees_observer_principal(served: Served, mode: str) -> None:
    async with mcp_client(served.mcp, served.observer, mode) as client:
        result = await client.call_tool("read_thing", {})

    assert result.structured_content is not None
    assert (result.structured_content["name"], result.structured_content["role"]) == ("bob", "observer")


@pytest.mark.anyio
@pytest.mark.parametrize("mode", PROTOCOL_MODES)
async def test_operator_may_call_motion_tool(served: Served, mode: str) -> None:
    async with mcp_client(served.mcp, served.operator, mode) as client:
        result = await client.call_tool("move_thing", {"x": 0.25})

    assert not result.is_error
    assert result.content[0].text == "moved to 0.25 by alice"


@pytest.mark.anyio
@pytest.mark.parametrize("mode", PROTOCOL_MODES)
async def test_observer_is_refused_motion_tool(served: Served, mode: str) -> None:
    async with mcp_client(served.mcp, served.observer, mode) as client:
        result = await client.call_tool("move_thing", {"x": 0.25})

    assert result.is_error
    assert "operator role required" in result.content[0].text


@pytest.mark.anyio
@pytest.mark.parametrize("mode", PROTOCOL_MODES)
async def test_authenticated_client_can_answer_elicitation(served: Served, mode: str) -> None:
    async with mcp_client(served.mcp, served.operator, mode) as client:
        result = await client.call_tool("approve_thing", {})

    assert not result.is_error
    assert result.content[0].text == "accept by Principal(name='alice', role='operator')"


# ------------------------------------------------------------------------ Host / Origin / health
def test_foreign_host_header_is_rejected(served: Served) -> None:
    response = post_initialize(served, Authorization=f"Bearer {served.operator}", Host=f"evil.example:{served.port}")

    assert response.status_code == 421


def test_foreign_origin_is_rejected(served: Served) -> None:
    response = post_initialize(served, Authorization=f"Bearer {served.operator}", Origin="http://evil.example")

    assert response.status_code == 403


def test_localhost_host_and_origin_are_accepted(served: Served) -> None:
    response = post_initialize(
        served,
        Authorization=f"Bearer {served.operator}",
        Host=f"localhost:{served.port}",
        Origin=f"http://localhost:{served.port}",
    )

    assert response.status_code == 200


def test_healthz_answers_without_token(served: Served) -> None:
    with httpx2.Client() as http:
        response = http.get(served.url + "/healthz")

    assert response.status_code == 200
    assert response.json() == {"status": "ok", "estop_latched": False}


def test_healthz_rejects_foreign_host(served: Served) -> None:
    with httpx2.Client() as http:
        response = http.get(served.url + "/healthz", headers={"Host": "evil.example"})

    assert response.status_code == 421


def test_unknown_path_needs_a_token(served: Served) -> None:
    with httpx2.Client() as http:
        response = http.get(served.url + "/anything")

    assert response.status_code == 401


# ------------------------------------------------------------------------ without tokens / serving
@pytest.mark.anyio
async def test_loopback_server_without_tokens_has_no_principal() -> None:
    port = free_port()
    app = build_http_app(make_server(), host="127.0.0.1", port=port, token_store=None)
    ready, shutdown = anyio.Event(), anyio.Event()

    async with anyio.create_task_group() as tg:
        tg.start_soon(functools.partial(serve_http, app, "127.0.0.1", port, ready=ready, shutdown=shutdown))
        with anyio.fail_after(10):
            await ready.wait()
            async with mcp_client(f"http://127.0.0.1:{port}/mcp", None, "legacy") as client:
                result = await client.call_tool("read_thing", {})
            shutdown.set()

    assert result.structured_content is not None and result.structured_content["name"] is None


@pytest.mark.anyio
async def test_shutdown_event_stops_server_with_a_session_open() -> None:
    port = free_port()
    app = build_http_app(make_server(), host="127.0.0.1", port=port, token_store=None)
    ready, shutdown = anyio.Event(), anyio.Event()
    stopped = anyio.Event()

    async def serve() -> None:
        await serve_http(app, "127.0.0.1", port, ready=ready, shutdown=shutdown, graceful_shutdown_s=1.0)
        stopped.set()

    with anyio.fail_after(10):  # a server held open by the SSE stream would time out here
        async with anyio.create_task_group() as tg:
            tg.start_soon(serve)
            await ready.wait()
            with contextlib.suppress(Exception):  # the client's own close races the server going away
                async with mcp_client(f"http://127.0.0.1:{port}/mcp", None, "legacy") as client:
                    await client.call_tool("read_thing", {})  # a legacy session keeps an SSE stream open
                    shutdown.set()
                    await stopped.wait()

    assert stopped.is_set()


@pytest.mark.anyio
async def test_serve_http_reports_busy_port_as_configuration_error() -> None:
    app = build_http_app(make_server(), host="127.0.0.1", port=0, token_store=None)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]

        with pytest.raises(ConfigurationError, match=f"127.0.0.1:{port}"):
            await serve_http(app, "127.0.0.1", port)


# ------------------------------------------------------------------------ bind safety / roles
@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "example.com", ""])
def test_non_loopback_bind_without_tokens_is_refused(host: str) -> None:
    with pytest.raises(ConfigurationError, match="without bearer tokens"):
        check_bind_safety(host, None)


def test_non_loopback_bind_with_tokens_is_allowed(tmp_path: Path) -> None:
    path = tmp_path / "tokens.json"
    TokenStore.add(path, "operator")

    check_bind_safety("0.0.0.0", TokenStore.load(path))


@pytest.mark.parametrize("host", ["127.0.0.1", "127.3.2.1", "::1", "[::1]", "localhost", "::ffff:127.0.0.1"])
def test_loopback_bind_without_tokens_is_allowed(host: str) -> None:
    check_bind_safety(host, None)


@pytest.mark.parametrize(
    ("tool", "group"),
    [
        ("get_robot_state", "introspect"),
        ("camera_snapshot", "perception"),
        ("get_safety_status", "safety"),
        ("stop_motion", "safety"),
        ("estop", "safety"),
    ],
)
def test_observer_may_call_introspection_perception_and_stop_tools(tool: str, group: str) -> None:
    spec = spec_of(tool)
    assert spec is not None and spec.group == group
    assert role_allows("observer", tool)


@pytest.mark.parametrize(
    ("tool", "group"),
    [("execute_plan", "motion"), ("reset_estop", "safety"), ("error_recovery", "safety"), ("unknown", None)],
)
def test_observer_may_not_call_other_tools(tool: str, group: str | None) -> None:
    assert getattr(spec_of(tool), "group", None) == group
    assert not role_allows("observer", tool)


def test_operator_may_call_everything() -> None:
    assert role_allows("operator", "reset_estop")
    assert role_allows("operator", "unknown")


def test_unknown_role_may_call_nothing() -> None:
    assert not role_allows("admin", "estop")
