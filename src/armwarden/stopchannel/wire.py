"""The stop channel's HTTP/1.1 subset: a bounded, minimal parser and the answers.

Why a hand-written subset: the channel must not depend on anything that can queue, buffer
without bound or run on the event loop. It understands exactly two requests —
``POST /estop`` with ``Authorization: Bearer <token>`` and an optional body of at most
`MAX_BODY_BYTES` announced by ``Content-Length``, and the operator console's
``POST /console-estop`` with at most one form field ``ticket`` (a "simple" cross-origin request
a browser sends without a CORS preflight) — and refuses everything else with a fixed, short
answer. Every function here is pure: bytes in, a value or an `HttpRefusal` out.
"""

from __future__ import annotations

import html
import json
import re
from dataclasses import dataclass
from urllib.parse import unquote_plus

from armwarden.safety.estop import flatten_reason

__all__ = [
    "CONSOLE_ESTOP_PATH",
    "ESTOP_PATH",
    "FORM_CONTENT_TYPE",
    "MAX_BODY_BYTES",
    "MAX_HEAD_BYTES",
    "MAX_TICKET_CHARS",
    "REASON_LIMIT",
    "HttpRefusal",
    "RequestHead",
    "bearer_token",
    "find_head_end",
    "parse_console_form",
    "parse_head",
    "parse_reason",
    "render_html_response",
    "render_response",
]

ESTOP_PATH = "/estop"
#: the operator console's E-STOP button posts here (a form, no bearer token)
CONSOLE_ESTOP_PATH = "/console-estop"
FORM_CONTENT_TYPE = "application/x-www-form-urlencoded"
#: longest console ticket accepted [characters]
MAX_TICKET_CHARS = 128
#: largest request line + headers accepted, terminator included [bytes]
MAX_HEAD_BYTES = 4096
#: largest body accepted [bytes]
MAX_BODY_BYTES = 1024
#: longest reason passed on to the latch [characters]
REASON_LIMIT = 200

_HEAD_END = re.compile(rb"\r?\n\r?\n")
_REQUEST_LINE = re.compile(r"([!#$%&'*+.^_`|~0-9A-Za-z-]+) (\S+) HTTP/1\.[01]")
_FIELD = re.compile(r"([!#$%&'*+.^_`|~0-9A-Za-z-]+):[ \t]*(.*?)[ \t]*")
_FORM_PAIR = re.compile(r"([A-Za-z0-9_.~%+-]*)=([A-Za-z0-9_.~%+-]*)")
_TICKET = re.compile(r"[A-Za-z0-9_-]+")
_PATHS = (ESTOP_PATH, CONSOLE_ESTOP_PATH)
_SINGLE_FIELDS = ("authorization", "content-length", "transfer-encoding", "origin")
_REASONS = {
    200: "OK",
    400: "Bad Request",
    401: "Unauthorized",
    403: "Forbidden",
    404: "Not Found",
    405: "Method Not Allowed",
    408: "Request Timeout",
    413: "Content Too Large",
    415: "Unsupported Media Type",
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
    """What the channel needs from a valid ``POST /estop`` or ``POST /console-estop`` head."""

    authorization: str | None
    content_length: int
    content_type: str
    path: str = ESTOP_PATH
    #: the browser's Origin header (None when the client sent none, e.g. curl)
    origin: str | None = None


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
    if target not in _PATHS:
        raise HttpRefusal(404, f"not found; the only resources are {ESTOP_PATH} and {CONSOLE_ESTOP_PATH}")
    if method != "POST":
        raise HttpRefusal(405, f"{target} accepts POST only", (("Allow", "POST"),))
    fields: dict[str, str] = {}
    for line in lines[1:]:
        if not line:
            continue  # the terminating blank line(s)
        field = _FIELD.fullmatch(line)
        if field is None:
            raise HttpRefusal(400, "malformed header line")
        name, value = field.group(1).lower(), field.group(2)
        if name in fields and name in _SINGLE_FIELDS:
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
        path=target,
        origin=fields.get("origin"),
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


def parse_console_form(body: bytes, content_type: str) -> str | None:
    """The ``ticket`` of a console E-STOP form, or None when the form carries none.

    Accepted: an empty body, or ``ticket=<value>`` as an ``application/x-www-form-urlencoded``
    body (what an HTML form or ``fetch`` with `URLSearchParams` sends). Any other field, a second
    ``ticket``, or a value that is not a plain URL-safe token is refused (`HttpRefusal` 400/415):
    the stop is not issued on a request the console would never send.
    """
    if not body:
        return None
    if content_type != FORM_CONTENT_TYPE:
        raise HttpRefusal(415, f"{CONSOLE_ESTOP_PATH} takes an {FORM_CONTENT_TYPE} form")
    if not body.isascii():
        raise HttpRefusal(400, "malformed form")
    ticket: str | None = None
    for pair in body.decode("ascii").split("&"):
        match = _FORM_PAIR.fullmatch(pair)
        if match is None:
            raise HttpRefusal(400, "malformed form")
        name, value = unquote_plus(match.group(1)), unquote_plus(match.group(2))
        if name != "ticket":
            raise HttpRefusal(400, "unexpected form field; the only field is ticket")
        if ticket is not None:
            raise HttpRefusal(400, "duplicate ticket field")
        if len(value) > MAX_TICKET_CHARS or (value and _TICKET.fullmatch(value) is None):
            raise HttpRefusal(400, "malformed ticket")
        ticket = value
    return ticket or None


def render_html_response(status: int, message: str, back_url: str | None) -> bytes:
    """A complete ``Connection: close`` response with a tiny HTML page: `message` and a link back.

    For the console's E-STOP form when the page has no script: the browser shows this page.
    Everything is escaped; the page may load nothing and run nothing.
    """
    link = "" if back_url is None else f'<p><a href="{html.escape(back_url)}">Back to the console</a></p>'
    body = (
        '<!doctype html><html lang="en"><head><meta charset="utf-8"><title>ArmWarden E-STOP</title></head>'
        f'<body><p id="estop-result">{html.escape(message)}</p>{link}</body></html>'
    ).encode()
    lines = [
        f"HTTP/1.1 {status} {_REASONS.get(status, 'Error')}",
        "Content-Type: text/html; charset=utf-8",
        f"Content-Length: {len(body)}",
        "Connection: close",
        "Cache-Control: no-store",
        "Content-Security-Policy: default-src 'none'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'",
        "X-Content-Type-Options: nosniff",
        "Referrer-Policy: no-referrer",
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body


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
