"""`armwarden serve`: assemble policy, robot model, backend, audit log and Guard, then serve MCP.

Start-up refuses (exit 2, before serving) on an invalid policy, an unavailable backend, an audit
log that cannot be opened, or an unsafe bind. On SIGTERM, SIGINT or end of stdin the daemon
stops the arm and the gripper, closes the backend and writes a final audit record.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from armwarden import __version__
from armwarden.backends import create_backend
from armwarden.backends.base import Backend
from armwarden.errors import ArmWardenError, BackendUnavailable, ConfigurationError, PolicyError
from armwarden.guard import Guard
from armwarden.policy import Policy, load_policy
from armwarden.preflight import load_runtime_model
from armwarden.robot import build_robot
from armwarden.safety.audit import AuditLog, hmac_key_from_env
from armwarden.server.app import ArmWardenServer

logger = logging.getLogger("armwarden")

EXIT_REFUSED = 2
#: GIL hand-off interval while planning runs on its worker thread: bounds how long a stop request
#: on the event loop can wait for the interpreter [s] (CPython's default is 5 ms)
SWITCH_INTERVAL_S = 0.0005
#: after SIGTERM/SIGINT on stdio: time for cancelled calls to stop the arm and audit themselves [s]
SIGNAL_GRACE_S = 0.3


class FakeBackendConfig(BaseModel):
    """`--backend-config` for the fake backend (strict, like every config file)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    speedup: float = Field(default=1.0, gt=0, le=1000, description="Time scaling of execution (2 = twice as fast)")
    table_height_m: float | None = Field(default=None, description="Virtual table plane z [m] producing contact force")
    table_stiffness_n_per_m: float = Field(default=20000.0, gt=0, description="Table stiffness [N/m]")
    wrench: bool = Field(default=True, description="Provide an external wrench estimate")


@dataclass
class Assembly:
    policy: Policy
    backend: Backend
    audit: AuditLog
    guard: Guard
    server: ArmWardenServer


def _load_backend_config(name: str, path: str | None) -> dict[str, Any]:
    if path is None:
        return {}
    try:
        document = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigurationError(f"cannot read backend config {path}: {exc}") from exc
    if name == "fake":
        try:
            return FakeBackendConfig.model_validate(document).model_dump()
        except ValidationError as exc:
            raise ConfigurationError(f"invalid fake backend config {path}: {exc}") from exc
    return {"config_path": path}


def assemble(policy: Policy, backend_name: str, backend_config: str | None, audit_path: str,
             **backend_overrides: Any) -> tuple[Policy, Backend, AuditLog, Any, Any]:
    """Build everything that can fail before serving (each failure is a clean exit 2)."""
    runtime = load_runtime_model(policy)
    state_robot = build_robot(policy)
    options = _load_backend_config(backend_name, backend_config) | backend_overrides
    robot_cfg = policy.robot
    backend = create_backend(
        backend_name,
        robot=state_robot,
        policy=policy,
        description=robot_cfg.description,
        home=list(robot_cfg.home_joint_positions),
        **options,
    )
    audit = AuditLog(audit_path, hmac_key=hmac_key_from_env())
    return policy, backend, audit, runtime, state_robot


def _previewer():
    try:
        from armwarden.server.preview import render_plan_preview
    except ImportError:  # pragma: no cover - the preview module is part of the package
        return None

    def preview(runtime, trajectory, report):
        return render_plan_preview(runtime.robot, runtime.envelope.limits, trajectory, report)

    return preview


async def open_assembly(policy: Policy, backend: Backend, audit: AuditLog, runtime: Any, state_robot: Any) -> Assembly:
    try:
        await backend.open()
    except ArmWardenError:
        raise
    except Exception as exc:
        raise BackendUnavailable(f"backend {backend.name} could not be opened: {exc}") from exc
    guard = Guard(policy, runtime, state_robot, backend, audit=audit, previewer=_previewer())
    server = ArmWardenServer(guard)
    return Assembly(policy, backend, audit, guard, server)


async def close_assembly(assembly: Assembly, why: str) -> None:
    """Stop the arm and gripper, close the backend, write the final record. Safe to call twice."""
    with anyio.CancelScope(shield=True):
        detail = why
        try:
            await assembly.backend.stop()
        except Exception as exc:  # the shutdown must go on; the record says the stop failed
            detail = f"{why}; stop failed: {exc}"
            logger.error("stop at shutdown failed: %s", exc)
        await assembly.backend.close()
        if not assembly.audit.closed:
            await assembly.audit.append_async("shutdown", outcome="ok", detail=detail)
            assembly.audit.close()


async def _run(args: argparse.Namespace, parts: tuple) -> None:
    assembly = await open_assembly(*parts)
    await assembly.audit.append_async(
        "startup",
        outcome="ok",
        detail=f"armwarden {__version__} serving {args.transport} with the {args.backend} backend",
        extra={"policy": str(args.policy or "bundled fr3"), "dry_run": assembly.policy.dry_run,
               "tools": assembly.server.tools},
    )
    why = "shutdown"
    shutdown = anyio.Event()
    try:
        async with anyio.create_task_group() as group:
            async def on_signals() -> None:
                nonlocal why
                with anyio.open_signal_receiver(signal.SIGTERM, signal.SIGINT) as signals:
                    async for signum in signals:
                        why = f"signal {signal.Signals(signum).name}"
                        with anyio.CancelScope(shield=True):  # the arm stops first, whatever follows
                            try:
                                await assembly.backend.stop()
                            except Exception as exc:
                                logger.error("stop on %s failed: %s", why, exc)
                        if args.transport == "http":
                            shutdown.set()  # uvicorn drains and returns; in-flight executions stop
                            return
                        group.cancel_scope.cancel()
                        if args.transport == "stdio":
                            # The SDK reads stdin in a worker thread that cancellation cannot interrupt,
                            # so the group would not unwind until the client closes stdin. Let the
                            # cancelled calls stop and record, then stop, close and record here and exit.
                            with anyio.CancelScope(shield=True):
                                await anyio.sleep(SIGNAL_GRACE_S)
                                await close_assembly(assembly, why)
                            logging.shutdown()
                            sys.stderr.flush()
                            os._exit(0)
                        return

            group.start_soon(on_signals)
            if args.transport == "stdio":
                await _serve_stdio(assembly)
                why = "end of stdin"
            else:
                await _serve_http(args, assembly, shutdown)
            group.cancel_scope.cancel()
    finally:
        await close_assembly(assembly, why)


async def _serve_stdio(assembly: Assembly) -> None:
    from armwarden.transport.jsonrpc import duplicate_id_message
    from armwarden.transport.stdio import serve_stdio

    async def on_duplicate(method: str, params: Mapping[str, Any] | None, request_id: Any) -> None:
        tool = params.get("name") if method == "tools/call" and params is not None else None
        arguments = params.get("arguments") if tool is not None and params is not None else None
        await assembly.audit.append_async("request_refused", tool=None if tool is None else str(tool),
                                          arguments=arguments, outcome="duplicate_request_id",
                                          detail=f"{method} refused: {duplicate_id_message(request_id)}")

    await serve_stdio(assembly.server.mcp, on_duplicate=on_duplicate)


async def _serve_http(args: argparse.Namespace, assembly: Assembly, shutdown: anyio.Event) -> None:
    from armwarden.transport.http import build_http_app, current_principal, serve_http
    from armwarden.transport.tokens import TokenStore

    tokens = TokenStore.load(args.auth_tokens) if args.auth_tokens else None

    async def on_abandoned(tool: str, arguments: dict[str, Any], request_id: Any, cancelled: bool | None) -> None:
        principal = current_principal()
        await assembly.guard.abandoned_call(tool, arguments, request_id, cancelled,
                                            principal=None if principal is None else principal.name)

    # /healthz answers without a token: it says only that the daemon is up, never the arm's state
    app = build_http_app(assembly.server.mcp, host=args.host, port=args.port, token_store=tokens,
                         on_abandoned=on_abandoned, allowed_hosts=getattr(args, "allowed_host", []) or [],
                         allowed_origins=getattr(args, "allowed_origin", []) or [])
    await serve_http(app, args.host, args.port, shutdown=shutdown)


def serve_command(args: argparse.Namespace) -> int:
    from armwarden.policy import bundled_policy

    policy_path = Path(args.policy) if args.policy else bundled_policy()
    try:
        policy = load_policy(policy_path).with_dry_run(args.dry_run)
        if args.transport == "http":
            from armwarden.transport.http import check_bind_safety
            from armwarden.transport.tokens import TokenStore

            check_bind_safety(args.host, TokenStore.load(args.auth_tokens) if args.auth_tokens else None)
        parts = assemble(policy, args.backend, args.backend_config, args.audit_log)
    except PolicyError as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except ArmWardenError as exc:
        print(f"armwarden: refusing to start: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        anyio.run(_run, args, parts)
    except ArmWardenError as exc:
        print(f"armwarden: refusing to start: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt:  # pragma: no cover - the signal receiver normally handles it
        pass
    return 0
