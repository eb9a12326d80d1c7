"""``armwarden snapshot CAMERA --out FILE --url URL --token-file FILE``: one camera picture, from a shell.

Why a client of the running daemon and not a backend of its own: the picture is taken by the
daemon's `camera_snapshot` tool, called through the official MCP SDK's streamable HTTP client
like any agent's call. So the policy's camera allowlist, the rate limits and the audit record
(principal: the token's name; the picture's size, never its pixels) apply as they do to every
call, and the backend sees one kind of request. Exit status: 0 the file was written; 1 the call
failed (an unknown camera, a refused token, an unreachable daemon, a refusal); 2 the arguments
cannot be used (an unreadable token file, a URL that is not http(s)).
"""

from __future__ import annotations

import argparse
import base64
import binascii
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from armwarden.safety.estop import flatten_reason
from armwarden.tokenfile import read_token_file

__all__ = ["Snapshot", "SnapshotFailed", "add_snapshot_arguments", "snapshot_command", "take_snapshot"]

EXIT_OK, EXIT_FAILED, EXIT_INVALID = 0, 1, 2
#: the official SDK's client names itself with this in the daemon's log
CLIENT_NAME = "armwarden-snapshot"


class SnapshotFailed(Exception):
    """The daemon gave no picture; the message says why (for the shell, one line)."""


@dataclass(frozen=True)
class Snapshot:
    """What `camera_snapshot` answered: the picture and its metadata."""

    camera: str
    width: int
    height: int
    stamp: float
    mime_type: str
    data: bytes


def add_snapshot_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``CAMERA --out FILE --url URL --token-file FILE [--timeout S]``."""
    parser.add_argument("camera", metavar="CAMERA", help="camera name, one the policy allows (perception.cameras)")
    parser.add_argument("--out", required=True, metavar="FILE", help="where to write the picture (PNG)")
    parser.add_argument("--url", required=True, metavar="URL", help="the daemon's MCP endpoint, e.g. http://127.0.0.1:8765/mcp")
    parser.add_argument("--token-file", required=True, metavar="FILE", help="file holding just a bearer token")
    parser.add_argument("--timeout", type=float, default=30.0, metavar="S", help="seconds for the whole call (default 30)")


def snapshot_command(args: argparse.Namespace) -> int:
    """The body of ``armwarden snapshot``: see the module docstring for the exit status."""
    try:
        token = read_token_file(args.token_file)
        parts = urlsplit(args.url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"--url must look like http://127.0.0.1:PORT/mcp, got {args.url!r}")
        if not (args.timeout > 0):
            raise ValueError(f"--timeout must be a positive number of seconds, got {args.timeout}")
    except ValueError as exc:
        print(f"armwarden: snapshot: {exc}", file=sys.stderr)
        return EXIT_INVALID
    import anyio

    try:
        snapshot = anyio.run(take_snapshot, args.url, token, args.camera, args.timeout)
        out = Path(args.out)
        _write_atomically(out, snapshot.data)
    except SnapshotFailed as exc:
        print(f"armwarden: snapshot FAILED: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except OSError as exc:
        print(f"armwarden: snapshot FAILED: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_FAILED
    kind = snapshot.mime_type.removeprefix("image/").upper()
    print(f"armwarden: wrote {out} ({kind}, {snapshot.width}x{snapshot.height} px, {len(snapshot.data)} bytes) "
          f"from camera {snapshot.camera!r}")
    return EXIT_OK


async def take_snapshot(url: str, token: str, camera: str, timeout_s: float = 30.0) -> Snapshot:
    """Call the daemon's `camera_snapshot` at `url` with `token`; the picture, or `SnapshotFailed`."""
    import anyio
    import httpx2
    import mcp_types as types
    from mcp import Client
    from mcp.client.streamable_http import streamable_http_client

    statuses: list[tuple[int, str]] = []

    async def note_refusals(response: httpx2.Response) -> None:
        if response.status_code in (401, 403):
            await response.aread()
            statuses.append((response.status_code, response.text))

    try:
        with anyio.fail_after(timeout_s):
            async with httpx2.AsyncClient(headers={"Authorization": f"Bearer {token}"}, timeout=timeout_s,
                                          event_hooks={"response": [note_refusals]}) as http, \
                    Client(streamable_http_client(url, http_client=http),
                           client_info=types.Implementation(name=CLIENT_NAME, version="1")) as client:
                result = await client.call_tool("camera_snapshot", {"camera": camera})
    except TimeoutError as exc:
        raise SnapshotFailed(f"the daemon at {url} did not answer within {timeout_s:g} s") from exc
    except Exception as exc:  # the SDK wraps what went wrong in exception groups
        raise SnapshotFailed(_why(url, exc, statuses)) from exc
    return _picture_of(result, camera)


def _picture_of(result: Any, camera: str) -> Snapshot:
    texts = [block.text for block in result.content if getattr(block, "type", "") == "text"]
    if result.is_error:
        said = flatten_reason(" ".join(texts) or "no message", 400)
        if "camera_snapshot" in said and ("unknown tool" in said.lower() or "not found" in said.lower()):
            said += " (the daemon serves no camera_snapshot: its policy does not enable perception, or its backend has no camera)"
        raise SnapshotFailed(f"the daemon refused: {said}")
    images = [block for block in result.content if getattr(block, "type", "") == "image"]
    if not images:
        raise SnapshotFailed("the daemon answered without a picture")
    try:
        data = base64.b64decode(images[0].data, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise SnapshotFailed(f"the daemon's picture is not valid base64: {exc}") from exc
    meta = result.structured_content if isinstance(result.structured_content, dict) else {}
    return Snapshot(camera=str(meta.get("camera", camera)), width=int(meta.get("width", 0)),
                    height=int(meta.get("height", 0)), stamp=float(meta.get("stamp", 0.0)),
                    mime_type=str(getattr(images[0], "mime_type", None) or "image/png"), data=data)


def _why(url: str, exc: BaseException, statuses: list[tuple[int, str]]) -> str:
    """One line for what went wrong before an answer: a refused token, no daemon, another error."""
    import httpx2

    if statuses:
        status, body = statuses[-1]
        said = flatten_reason(body, 200) or "no message"
        if status == 401:
            return f"the daemon at {url} refused the token (401: {said}); check --token-file"
        return f"the daemon at {url} refused the request (403: {said})"
    leaves = _leaves(exc)
    for leaf in leaves:
        if isinstance(leaf, (httpx2.ConnectError, ConnectionError)):
            return f"cannot reach the daemon at {url}: {leaf}; is `armwarden serve --transport http` running there?"
        if isinstance(leaf, httpx2.TimeoutException):
            return f"the daemon at {url} did not answer in time: {leaf}"
    return f"the call to {url} failed: {'; '.join(flatten_reason(f'{type(leaf).__name__}: {leaf}', 200) for leaf in leaves)}"


def _leaves(exc: BaseException) -> list[BaseException]:
    """The errors inside `exc`'s exception groups (3.10 has no built-in BaseExceptionGroup)."""
    inner = getattr(exc, "exceptions", None)
    if isinstance(inner, (list, tuple)):
        return [leaf for each in inner if isinstance(each, BaseException) for leaf in _leaves(each)]
    return [exc]


def _write_atomically(path: Path, data: bytes) -> None:
    """Write `data` to `path` whole or not at all (a reader never sees half a picture)."""
    directory = path.parent if str(path.parent) else Path(".")
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=directory)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)  # as any file the shell would create (mkstemp makes 0600)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
