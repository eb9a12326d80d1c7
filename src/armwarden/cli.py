"""`armwarden` command line: serve, init, check-policy, audit verify|tail|replay, tokens add|list|revoke.

Exit status 2 means "refused to start / invalid input" (bad policy, unavailable backend,
unopenable audit log, unsafe bind); 1 means a check failed (e.g. a broken audit chain).
Logs go to stderr only: on stdio, stdout carries nothing but MCP.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from armwarden import __version__
from armwarden.audit import DEFAULT_COMMIT_WINDOW_S
from armwarden.backends import backend_names, backends_help
from armwarden.calibration.arguments import add_calibrate_arguments
from armwarden.core.errors import ArmWardenError, PolicyError
from armwarden.daemon.options import EXIT_REFUSED, ServeOptions
from armwarden.evaluation.arguments import EVAL_BACKENDS, add_eval_arguments
from armwarden.onboarding.command import add_init_arguments, init_command
from armwarden.policy import bundled_policy  # also re-exported here for older importers
from armwarden.snapshot_cli import add_snapshot_arguments, snapshot_command
from armwarden.stopchannel.client import add_estop_arguments, estop_command

EXIT_OK = 0
EXIT_FAILED = 1


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="armwarden", description="Safety-first MCP server daemon for robot arms.")
    parser.add_argument("--version", action="version", version=f"armwarden {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    serve = commands.add_parser("serve", help="run the MCP server (stdio or streamable HTTP)")
    serve.add_argument("--policy", default=None, help="safety policy YAML (default: the bundled FR3 policy)")
    serve.add_argument("--backend", default="fake", choices=backend_names(), help=backends_help())
    serve.add_argument("--backend-config", default=None,
                       help="the backend's options YAML (strict; e.g. the fake's speedup, later ROS names, CAN ids, scene)")
    serve.add_argument("--transport", default="stdio", choices=["stdio", "http"])
    serve.add_argument("--host", default="127.0.0.1")
    serve.add_argument("--port", type=int, default=8765)
    serve.add_argument("--audit-log", default="armwarden-audit.jsonl", help="append-only audit log (JSONL)")
    serve.add_argument("--audit-commit-window-ms", type=float, default=DEFAULT_COMMIT_WINDOW_S * 1e3, metavar="MS",
                       help="read-only calls' audit records are written and fsynced within this window instead of "
                            "before their reply (0..1000; 0 = every record before its reply). Actuating calls, approvals, "
                            "refusals of actuating calls, e-stops and resets are always on disk before their reply")
    serve.add_argument("--auth-tokens", default=None, help="bearer token file (see `armwarden tokens`)")
    serve.add_argument("--allowed-host", action="append", default=[], metavar="HOST[:PORT]",
                       help="extra Host header value clients may use (repeatable; e.g. the LAN name of this machine)")
    serve.add_argument("--allowed-origin", action="append", default=[], metavar="ORIGIN",
                       help="extra browser Origin allowed (repeatable; e.g. http://console.local:8080)")
    serve.add_argument("--estop-port", type=int, default=None, metavar="PORT",
                       help="serve the independent stop channel (POST /estop, any token) on this port; needs --auth-tokens")
    serve.add_argument("--estop-host", default="127.0.0.1", help="address of the stop channel (default loopback)")
    serve.add_argument("--console-port", type=int, default=None, metavar="PORT",
                       help="stdio: serve the operator console on this port (over HTTP it is at /console)")
    serve.add_argument("--console-host", default="127.0.0.1", help="address of --console-port (default loopback)")
    serve.add_argument("--no-console", action="store_true", help="HTTP: do not serve the operator console at /console")
    serve.add_argument("--console-estop-needs-sign-in", action="store_true",
                       help="the console's E-STOP needs sign-in also from this machine (default: loopback may stop unsigned)")
    serve.add_argument("--dry-run", action="store_true", help="validate and ask, never actuate")
    serve.add_argument("--actuation-journal", default=None, metavar="FILE",
                       help="for evaluation (`armwarden eval`): append every actuating or stopping call that reaches "
                            "the backend, below the Guard, to FILE as JSON lines")
    serve.add_argument("--eval-backend-death", action="store_true",
                       help="EVALUATION ONLY (`armwarden eval`): on SIGUSR2 the simulated backend dies mid-run (fake: "
                            "its control thread, mujoco: its physics thread, can: its emulator stops); refused for "
                            "any backend that may drive a real arm")
    serve.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])

    add_estop_arguments(commands.add_parser(
        "estop", help="e-stop a running daemon through its stop channel (--url) or SIGUSR1 (--pid)"))
    add_snapshot_arguments(commands.add_parser(
        "snapshot", help="write one camera picture of a running daemon (its camera_snapshot tool) to a file"))

    add_init_arguments(commands.add_parser(
        "init", help="write a checked policy, fitted collision geometry and a picture for any URDF or MJCF arm"))
    add_calibrate_arguments(commands.add_parser(
        "calibrate-contact", help="run safe approved motions, record the joint-torque observer's residuals and "
        "recommend per-joint contact limits"))

    add_eval_arguments(commands.add_parser(
        "eval", help="run the safety evaluation: unsafe requests refused with no actuation, safe ones executed, "
        "against the real daemon (simulated arms, CAN on its emulator, the fake ROS cell; on your own ROS cell only "
        "approved plans: it approves its own motions)"),
        EVAL_BACKENDS)

    check = commands.add_parser("check-policy", help="validate a policy and print what it allows")
    check.add_argument("policy", nargs="?", default=None, help="policy YAML (default: the bundled FR3 policy)")

    audit = commands.add_parser("audit", help="verify or read an audit log").add_subparsers(dest="audit_command", required=True)
    verify = audit.add_parser("verify", help="prove the hash chain (exit 0 intact, 1 broken)")
    verify.add_argument("file")
    tail = audit.add_parser("tail", help="print the last records (with filters: the last ones that match all of them)")
    tail.add_argument("file")
    tail.add_argument("-n", type=int, default=20)
    tail.add_argument("--tool", default=None, help="only calls of this tool")
    tail.add_argument("--principal", default=None, help="only calls made with this HTTP token name")
    tail.add_argument("--status", default=None, help="only records with this outcome (ok, refused, invalid, ...) or "
                      "result status (a plan's ok/needs_approval/rejected, an execution's succeeded/aborted/dry_run)")
    tail.add_argument("--since", default=None, metavar="TIME", help="only records written at or after this ISO 8601 "
                      "time (UTC unless a zone is given), e.g. 2026-11-24T04:10:00Z")
    replay = audit.add_parser("replay", help="re-plan every recorded plan request under a candidate policy (offline) "
                              "and report what it would have done differently (exit 0 report written, 1 broken or "
                              "unreadable log, 2 invalid policy)")
    replay.add_argument("file", help="the audit log (JSONL) of the sessions to replay")
    replay.add_argument("--policy", required=True, help="the candidate policy YAML")
    replay.add_argument("--original", default=None, help="re-plan under this policy too, as the original outcome "
                        "(default: the outcomes recorded in the log)")
    replay.add_argument("--json", default=None, metavar="FILE", help="also write the report's data as JSON to FILE")
    replay.add_argument("--allow-broken", action="store_true", help="replay the trusted prefix of a log whose chain "
                        "is broken (the report says from which line nothing is trusted)")

    tokens = commands.add_parser("tokens", help="manage HTTP bearer tokens").add_subparsers(dest="tokens_command", required=True)
    add = tokens.add_parser("add", help="create a token (printed once; only its hash is stored)")
    add.add_argument("file")
    add.add_argument("--role", required=True, choices=["observer", "operator", "agent"],
                     help="operator: a human; agent: an MCP client (the tools of an operator, no console sign-in)")
    add.add_argument("--name", default=None)
    listing = tokens.add_parser("list", help="list token names and roles")
    listing.add_argument("file")
    revoke = tokens.add_parser("revoke", help="revoke a token by name")
    revoke.add_argument("file")
    revoke.add_argument("name")
    return parser


def check_policy_command(path: str | None) -> int:
    from armwarden.policy import load_policy, summarize_policy
    from armwarden.preflight import load_runtime_model

    policy_path = Path(path) if path else bundled_policy()
    try:
        policy = load_policy(policy_path)
        runtime = load_runtime_model(policy, str(policy_path))
    except PolicyError as exc:
        print(f"INVALID: {exc.source} ({len(exc.errors)} error{'s' if len(exc.errors) != 1 else ''})")
        for yaml_path, message in exc.errors:
            print(f"  {yaml_path}: {message}")
        return EXIT_REFUSED
    print(f"OK: {policy_path}")
    print(summarize_policy(policy))
    robot = runtime.robot
    print(
        f"Robot model: {len(robot.capsules)} collision capsules on {len({c.link for c in robot.capsules})} links, "
        f"{len(runtime.envelope.self_collision_pairs)} self-collision pairs; home configuration passes the envelope"
    )
    return EXIT_OK


def _tail(args: argparse.Namespace) -> int:
    """`audit tail`, with its record filters (exit 2 on a malformed --since)."""
    from armwarden import audit

    try:
        since = None if args.since is None else audit.parse_since(args.since)
    except ValueError as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    where = audit.RecordFilter(tool=args.tool, principal=args.principal, status=args.status, since=since)
    return audit.tail_command(args.file, args.n, where)


def serve_options(args: argparse.Namespace) -> ServeOptions:
    """The `serve` flags as the daemon's one typed record (its only contact with argparse)."""
    return ServeOptions(
        policy=args.policy, backend=args.backend, backend_config=args.backend_config, transport=args.transport,
        host=args.host, port=args.port, audit_log=args.audit_log,
        audit_commit_window_s=args.audit_commit_window_ms / 1e3, auth_tokens=args.auth_tokens,
        allowed_hosts=tuple(args.allowed_host), allowed_origins=tuple(args.allowed_origin),
        estop_port=args.estop_port, estop_host=args.estop_host, console_port=args.console_port,
        console_host=args.console_host, no_console=args.no_console,
        console_estop_needs_sign_in=args.console_estop_needs_sign_in, dry_run=args.dry_run,
        actuation_journal=args.actuation_journal, eval_backend_death=args.eval_backend_death)


def main(argv: Sequence[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    logging.basicConfig(
        stream=sys.stderr,
        level=getattr(args, "log_level", "WARNING"),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        if args.command == "check-policy":
            return check_policy_command(args.policy)
        if args.command == "init":
            return init_command(args)
        if args.command == "calibrate-contact":
            from armwarden.calibration.command import calibrate_command  # the daemon and Pinocchio: only here

            return calibrate_command(args)
        if args.command == "eval":
            from armwarden.evaluation.command import eval_command

            return eval_command(args)
        if args.command == "audit":
            from armwarden import audit

            if args.audit_command == "verify":
                return audit.verify_command(args.file, audit.hmac_key_from_env())
            if args.audit_command == "replay":
                from armwarden.replay import replay_command

                return replay_command(args.file, args.policy, original=args.original, json_path=args.json,
                                      allow_broken=args.allow_broken, key=audit.hmac_key_from_env())
            return _tail(args)
        if args.command == "tokens":
            from armwarden.transport import tokens

            if args.tokens_command == "add":
                return tokens.tokens_add_command(args.file, args.role, args.name)
            if args.tokens_command == "list":
                return tokens.tokens_list_command(args.file)
            return tokens.tokens_revoke_command(args.file, args.name)
        if args.command == "estop":
            return estop_command(args)
        if args.command == "snapshot":
            return snapshot_command(args)
        if args.command == "serve":
            from armwarden.daemon.serve import serve_command

            return serve_command(serve_options(args))
    except ArmWardenError as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except BrokenPipeError:  # output piped into `head` and the like: stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    return EXIT_FAILED  # pragma: no cover - argparse enforces the choices


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
