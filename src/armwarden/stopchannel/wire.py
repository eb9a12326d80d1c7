"""The stop channel's HTTP/1.1 subset: a bounded, minimal parser and the answers.

Why a hand-written subset: the channel must not depend on anything that can queue, buffer
without bound or run on the event loop. It understands exactly one request —
``POST /estop`` with ``Authorization: Bearer <token>`` and an optional body of at most
`MAX_BODY_BYTES` announced by ``Content-Length`` — and refuses everything else with a fixed,
short answer. Every function here is pure: bytes in, a value or an `HttpRefusal` out.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from armwarden.safety.estop import flatten_reason

__all__ = [
    "ESTOP_PATH",
    "MAX_BODY_BYTES",
    "MAX_HEAD_BYTES",
    "REASON_LIMIT",
    "HttpRefusal",
    "RequestHead",
    "bearer_token",
    "find_head_end",
    "parse_head",
    "parse_reason",
    "render_response",
]

ESTOP_PATH = "/estop"
#: largest request line + headers accepted, terminator included [bytes]
MAX_HEAD_BYTES = 4096
#: largest body accepted [bytes]
MAX_BODY_BYTES = 1024
#: longest reason passed on to the latch [characters]
REASON_LIMIT = 200

_HEAD_END = re.compile(rb"\r?\n\r?\n")
_REQUEST_LINE = re.compile(r"([!#$%&'*+.^_`|~0-9A-Za-z-]+) (\S+) HTTP/1\.[01]")
_FIELD = re.compile(r"([!#$%&'*+.^_`|~0-9A-Za-z-]+):[ \t]*(.*?)[ \t]*")
_REASONS = {
    200: "OK",
    400: "Bad Request",
    401: "Unauthorized",
    404: "Not Found",
    405: "Method Not Allowed",
    408: "Request Timeout",
    413: "Content Too Large",
    500: "Internal Server Error",
    501: "Not Implemented",
}


@dataclass(frozen=True)
class HttpRefusal(Exception):
    """A request answered with `status` and a one-line `message`; the stop is not issued."""

    status: int
    message: str
    headers: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class RequestHead:
    """What the channel needs from a valid ``POST /estop`` head."""

    authorization: str | None
    content_length: int
    content_type: str


def find_head_end(buffer: bytes | bytearray) -> int | None:
    """Index just past the blank line ending the head, or None while it is incomplete."""
    match = _HEAD_END.search(buffer, 0, MAX_HEAD_BYTES)
    return None if match is None else match.end()


def parse_head(head: bytes) -> RequestHead:
    """Check the request line and headers of `head`; raise `HttpRefusal` on anything else."""
    lines = head.decode("latin-1").split("\n")
    lines = [line.removesuffix("\r") for line in lines]
    request = _REQUEST_LINE.fullmatch(lines[0])
    if request is None:
        raise HttpRefusal(400, "malformed request line; expected 'POST /estop HTTP/1.1'")
    method, target = request.groups()
    if target != ESTOP_PATH:
        raise HttpRefusal(404, f"not found; the only resource is {ESTOP_PATH}")
    if method != "POST":
        raise HttpRefusal(405, f"{ESTOP_PATH} accepts POST only", (("Allow", "POST"),))
    fields: dict[str, str] = {}
    for line in lines[1:]:
        if not line:
            continue  # the terminating blank line(s)
        field = _FIELD.fullmatch(line)
        if field is None:
            raise HttpRefusal(400, "malformed header line")
        name, value = field.group(1).lower(), field.group(2)
        if name in fields and name in ("authorization", "content-length", "transfer-encoding"):
            raise HttpRefusal(400, f"duplicate {name} header")
        fields[name] = value
    if "transfer-encoding" in fields:
        raise HttpRefusal(501, "Transfer-Encoding is not supported; send Content-Length")
    length_text = fields.get("content-length", "0")
    if not length_text.isascii() or not length_text.isdigit() or len(length_text) > 9:
        raise HttpRefusal(400, "Content-Length must be a decimal number")
    if int(length_text) > MAX_BODY_BYTES:
        raise HttpRefusal(413, f"body larger than {MAX_BODY_BYTES} bytes")
    return RequestHead(
        authorization=fields.get("authorization"),
        content_length=int(length_text),
        content_type=fields.get("content-type", "").split(";")[0].strip().lower(),
    )


def bearer_token(authorization: str | None) -> str:
    """The token of a ``Bearer`` credential; `HttpRefusal` 401 when there is none."""
    scheme, _, token = (authorization or "").strip().partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise HttpRefusal(401, "a bearer token is required", (("WWW-Authenticate", 'Bearer realm="armwarden-estop"'),))
    return token.strip()


def parse_reason(body: bytes, content_type: str) -> str:
    """The reason in `body`, one line of at most `REASON_LIMIT` characters; never raises.

    A JSON object's ``reason`` member is used when the body is JSON; anything else (plain
    text, invalid JSON, other JSON values) is taken as text. A stop is never refused because
    of its reason.
    """
    if not body:
        return ""
    if content_type == "application/json" or body.lstrip()[:1] == b"{":
        try:
            document = json.loads(body)
        except (ValueError, RecursionError):
            document = None
        if isinstance(document, dict) and "reason" in document:
            return flatten_reason(document["reason"], REASON_LIMIT)
    return flatten_reason(body, REASON_LIMIT)


def render_response(status: int, payload: dict[str, object], headers: tuple[tuple[str, str], ...] = ()) -> bytes:
    """A complete ``Connection: close`` response with a JSON body."""
    body = json.dumps(payload, separators=(",", ":")).encode("utf-8")
    lines = [
        f"HTTP/1.1 {status} {_REASONS.get(status, 'Error')}",
        "Content-Type: application/json",
        f"Content-Length: {len(body)}",
        "Connection: close",
        "Cache-Control: no-store",
        *(f"{name}: {value}" for name, value in headers),
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body
