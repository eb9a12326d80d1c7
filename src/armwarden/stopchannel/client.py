"""Trigger an e-stop from outside the daemon: over the stop channel, or by signal.

`send_estop` is the one-shot HTTP client (standard library only, so it works from any script
next to the daemon); `estop_command` is the body of ``armwarden estop`` and
`add_estop_arguments` declares its options on an argparse sub-parser. With ``--pid``, the
signal goes first and the reason is written after it (`armwarden.stopchannel.reasons`), so a
stalled file system never holds the stop back; the command gives the write
`REASON_WRITE_BUDGET_S`, about as long as the daemon waits for it (`signals.REASON_GRACE_S`).
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from armwarden.safety.estop import flatten_reason
from armwarden.stopchannel.reasons import write_reason
from armwarden.stopchannel.wire import ESTOP_PATH
from armwarden.tokenfile import read_token_file

__all__ = [
    "EStopRefused",
    "EStopRequestError",
    "EStopTimeout",
    "EStopUnauthorized",
    "EStopUnreachable",
    "add_estop_arguments",
    "estop_command",
    "send_estop",
]

_MAX_ANSWER_BYTES = 64 * 1024


class EStopRequestError(Exception):
    """The e-stop request did not get a confirmed stop. Assume the arm has NOT been stopped."""


class EStopUnreachable(EStopRequestError):
    """Nothing answered at the URL (connection refused, reset, unknown host)."""


class EStopTimeout(EStopRequestError):
    """The channel did not answer within the timeout."""


class EStopUnauthorized(EStopRequestError):
    """The channel refused the token (401)."""


class EStopRefused(EStopRequestError):
    """The channel answered with another error; `status` is the HTTP status."""

    def __init__(self, status: int, message: str) -> None:
        self.status = status
        super().__init__(message)


#: how often a connection the channel dropped unanswered is tried again
RESET_RETRIES = 2
#: how long ``estop --pid`` gives writing its reason, after the signal, before it gives up [s]
REASON_WRITE_BUDGET_S = 0.5


def send_estop(url: str, token: str, reason: str = "", timeout_s: float = 2.0) -> dict[str, Any]:
    """POST an e-stop to `url` and return the channel's answer (``{"estopped": true, "event": N, ...}``).

    `url` is ``http://HOST:PORT`` or ``http://HOST:PORT/estop``; `timeout_s` bounds each socket
    operation. A connection the channel dropped before answering (it evicts idle connections when
    a flood fills it) is tried again, up to `RESET_RETRIES` times; a stop is safe to repeat.
    Raises an `EStopRequestError` subclass unless the stop was confirmed.
    """
    parts = urlsplit(url)
    if parts.scheme != "http" or not parts.hostname:
        raise EStopRequestError(f"stop channel URL must look like http://127.0.0.1:PORT/estop, got {url!r}")
    try:
        port = parts.port or 80
    except ValueError as exc:
        raise EStopRequestError(f"bad port in stop channel URL {url!r}") from exc
    path = parts.path if parts.path not in ("", "/") else ESTOP_PATH
    body = json.dumps({"reason": reason}).encode("utf-8") if reason else b""
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "application/json", "Connection": "close"}
    for attempt in range(RESET_RETRIES + 1):
        try:
            status, status_reason, raw = _post_once(parts.hostname, port, path, body, headers, timeout_s)
            break
        except TimeoutError as exc:
            raise EStopTimeout(f"stop channel at {url} did not answer within {timeout_s} s") from exc
        except (ConnectionResetError, BrokenPipeError, http.client.RemoteDisconnected) as exc:
            if attempt == RESET_RETRIES:
                raise EStopUnreachable(f"the stop channel at {url} dropped the connection {attempt + 1} times: {exc}") from exc
        except (OSError, http.client.HTTPException) as exc:
            raise EStopUnreachable(f"cannot reach the stop channel at {url}: {exc}") from exc
    else:  # pragma: no cover - the loop either breaks or raises
        raise EStopUnreachable(f"cannot reach the stop channel at {url}")
    try:
        answer = json.loads(raw)
    except ValueError:
        answer = {}
    if not isinstance(answer, dict):
        answer = {}
    message = flatten_reason(answer.get("error") or status_reason or "no message", 300)
    if status == 401:
        raise EStopUnauthorized(f"stop channel refused the token: {message}")
    if status != 200 or answer.get("estopped") is not True:
        raise EStopRefused(status, f"stop channel answered {status}: {message}")
    return answer


def _post_once(host: str, port: int, path: str, body: bytes, headers: dict[str, str],
               timeout_s: float) -> tuple[int, str, bytes]:
    """One POST: (status, reason phrase, at most `_MAX_ANSWER_BYTES` of the answer)."""
    connection = http.client.HTTPConnection(host, port, timeout=timeout_s)
    try:
        connection.request("POST", path, body=body, headers=headers)
        response = connection.getresponse()
        return response.status, response.reason, response.read(_MAX_ANSWER_BYTES)
    finally:
        connection.close()


def add_estop_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``[--url URL | --pid PID] [--token-file FILE] [--reason TEXT] [--timeout S]``."""
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--url", help="stop channel URL, e.g. http://127.0.0.1:PORT/estop")
    target.add_argument("--pid", type=int, help="send SIGUSR1 to this daemon process instead")
    parser.add_argument("--token-file", help="file holding just the bearer token (required with --url)")
    parser.add_argument("--reason", default="", help="why you stop (recorded in the audit log)")
    parser.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for each network step")


def estop_command(args: argparse.Namespace) -> int:
    """``armwarden estop``: 0 when the stop was confirmed (URL) or the signal sent (PID), else 1."""
    url, pid = getattr(args, "url", None), getattr(args, "pid", None)
    try:
        if pid is not None:
            if pid <= 0:  # 0 and negative numbers would signal whole process groups
                raise EStopRequestError(f"--pid must be a positive process id, got {pid}")
            reason = getattr(args, "reason", "") or ""
            signalled_ns = time.monotonic_ns()  # before the signal: the stop that answers it wakes later
            os.kill(pid, signal.SIGUSR1)  # the stop first: it never waits for the reason
            print(f"armwarden: sent SIGUSR1 (e-stop) to process {pid}; check its log for the event number",
                  flush=True)
            if reason:
                _hand_over_reason(pid, reason, signalled_ns)
            return 0
        if not url:
            raise EStopRequestError("give --url URL (with --token-file) or --pid PID")
        token_file = getattr(args, "token_file", None)
        if not token_file:
            raise EStopRequestError("--url needs --token-file FILE holding a bearer token")
        try:
            token = read_token_file(token_file)
        except ValueError as exc:
            raise EStopRequestError(str(exc)) from exc
        answer = send_estop(url, token, getattr(args, "reason", "") or "", getattr(args, "timeout", 2.0))
    except ProcessLookupError:
        return _fail(f"no process {pid}")
    except (EStopRequestError, OSError) as exc:
        return _fail(str(exc))
    print(f"armwarden: e-stop latched, event {answer.get('event')} (stop issued in {answer.get('stop_issued_ms')} ms)")
    return 0


def _hand_over_reason(pid: int, reason: str, signalled_ns: int, budget_s: float | None = None) -> Path | None:
    """Write `reason` for the daemon `pid`, signalled at `signalled_ns` (``time.monotonic_ns()``),
    within `budget_s` [s] (None: `REASON_WRITE_BUDGET_S`; a hung file system must not hang the
    command); None, said on stderr, when it was not written: the stop has gone out without it."""
    budget_s = REASON_WRITE_BUDGET_S if budget_s is None else budget_s
    outcome: list[Path | Exception] = []

    def write() -> None:
        try:
            outcome.append(write_reason(pid, reason, signalled_ns=signalled_ns))
        except Exception as exc:
            outcome.append(exc)

    writer = threading.Thread(target=write, name="armwarden-estop-reason", daemon=True)
    writer.start()
    writer.join(budget_s)
    done = outcome[0] if outcome else None
    if isinstance(done, Path):
        return done
    why = f"not written within {budget_s:g} s" if done is None else flatten_reason(str(done), 600)
    print(f"armwarden: the reason could not be handed over ({why}); the e-stop was sent without it", file=sys.stderr)
    return None


def _fail(message: str) -> int:
    print(f"armwarden: e-stop FAILED: {flatten_reason(message, 400)}", file=sys.stderr)
    return 1
