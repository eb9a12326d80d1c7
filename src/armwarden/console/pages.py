"""Server-rendered HTML: Jinja2 templates shipped in the package, autoescaped.

Every value on a page may carry text a model wrote (an e-stop reason, an audit detail), so the
environment escapes everything by default and the pages run under a Content-Security-Policy
that allows only the daemon's own script and style files: no inline script, no other origin.
A page says something after a redirect only by a code in its URL that maps to one of the fixed
texts of `MESSAGES`: a crafted link cannot put official-looking words (or a CSS class) on the
daemon's own page.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, Literal, get_args
from urllib.parse import urlencode

from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from starlette.responses import HTMLResponse

__all__ = ["MESSAGES", "SECURITY_HEADERS", "message_from_query", "message_query", "page_headers", "render",
           "render_fragment"]

MessageKind = Literal["ok", "error"]
#: what a page may say after a redirect, by the code in its URL (``?msg=CODE``, with ``&event=N``
#: where the text has ``{event}``): fixed texts and kinds, so nobody can put words on the daemon's
#: own page with a crafted link (the URL carries a code, never a text or a CSS class)
MESSAGES: dict[str, tuple[MessageKind, str]] = {
    "bad_token": ("error", "That token is not valid (unknown or revoked)."),
    "agent_token": ("error", "That is an agent's token (role agent, for MCP clients): the console is for humans. Sign "
                             "in with an operator or observer token."),
    "console_full": ("error", "The console already has as many sessions open as it allows, and no one else is signed "
                              "out to make room. Ask someone to sign out, or wait until a session ends."),
    "no_request": ("error", "No such approval request."),
    "estop_latched": ("ok", "E-STOP latched: event #{event}"),
    "estop_failed": ("error", "E-STOP FAILED: the stop may NOT have been issued. Use the hardware e-stop."),
    "released": ("ok", "E-stop #{event} released."),
    "release_refused": ("error", "Release refused: nothing was released. Type the number of the e-stop event latched "
                                 "now, shown on this page; any other number is refused."),
    "release_unrecorded": ("error", "Release refused: the audit log cannot record it, so nothing was released and "
                                    "the e-stop stays latched. Repair the audit log first."),
    "approved": ("ok", "Approved: the waiting call proceeds from this answer."),
    "declined": ("ok", "Declined: nothing moves."),
}
_EVENT_NUMBER = re.compile(r"[0-9]{1,9}")

#: headers on every console answer: no caching of live state, no framing, no referrer (an approval
#: link must not leak to another site), only the daemon's own scripts and styles
SECURITY_HEADERS = {
    "Cache-Control": "no-store",
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",  # no-referrer would make the browser send "Origin: null", refused
    "Content-Security-Policy": ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
                                "connect-src 'self'; form-action 'self'; frame-ancestors 'none'; base-uri 'none'"),
}



def page_headers(estop_origin: str | None) -> dict[str, str]:
    """`SECURITY_HEADERS` for pages whose E-STOP posts to the stop channel at `estop_origin`
    (``http://host:port``): the form and the script may post there too, and the browser names
    this origin in its Origin header (the channel checks it) instead of ``null``."""
    if estop_origin is None:
        return SECURITY_HEADERS
    csp = SECURITY_HEADERS["Content-Security-Policy"]
    csp = csp.replace("connect-src 'self'", f"connect-src 'self' {estop_origin}")
    csp = csp.replace("form-action 'self'", f"form-action 'self' {estop_origin}")
    # the origin only (no path, so no approval link) leaves for another origin
    return {**SECURITY_HEADERS, "Content-Security-Policy": csp, "Referrer-Policy": "strict-origin-when-cross-origin"}


def message_query(code: str, event: int | None = None) -> str:
    """The query string that makes a page say `MESSAGES[code]` (with `event` for ``{event}``)."""
    if code not in MESSAGES:
        raise KeyError(f"no console message {code!r}")
    return urlencode({"msg": code} if event is None else {"msg": code, "event": int(event)})


def message_from_query(query: Mapping[str, str]) -> tuple[str, MessageKind] | None:
    """The text and kind a page shows for its query string: a known code's fixed text (with an
    event number, digits only, where it needs one); None for anything else."""
    code = query.get("msg")
    if code not in MESSAGES:
        return None
    kind, text = MESSAGES[code]
    if "{event}" in text:
        event = query.get("event", "")
        if not _EVENT_NUMBER.fullmatch(event):
            return None
        text = text.format(event=int(event))
    return text, kind


_ENV = Environment(
    loader=PackageLoader("armwarden.console", "templates"),
    autoescape=select_autoescape(default=True, default_for_string=True),
    undefined=StrictUndefined,  # a missing value is a bug, not an empty string
    trim_blocks=True,
    lstrip_blocks=True,
)

_PAGE_DEFAULTS: dict[str, Any] = {"session": None, "message": None, "message_kind": "ok", "title": "console",
                                  "estop_url": None}


def render(template: str, *, status_code: int = 200, headers: dict[str, str] | None = None,
           **context: Any) -> HTMLResponse:
    """A whole page (`template` extends base.html); `base` (the console's path) must be given.
    `estop_url`: where the E-STOP button posts (the stop channel; None: the console's own route).
    `message_kind` (a CSS class) must be one of `MessageKind`'s."""
    if context.get("message_kind", "ok") not in get_args(MessageKind):
        raise ValueError(f"message kind {context['message_kind']!r} is not one of {get_args(MessageKind)}")
    html = _ENV.get_template(template).render({**_PAGE_DEFAULTS, **context})
    return HTMLResponse(html, status_code=status_code, headers=headers or SECURITY_HEADERS)


def render_fragment(template: str, **context: Any) -> HTMLResponse:
    """One live section (a `_name.html` template) for the page's refresh script."""
    return HTMLResponse(_ENV.get_template(template).render({**_PAGE_DEFAULTS, **context}), headers=SECURITY_HEADERS)
