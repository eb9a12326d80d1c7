"""Server-rendered HTML: Jinja2 templates shipped in the package, autoescaped.

Every value on a page may carry text a model wrote (an e-stop reason, an audit detail), so the
environment escapes everything by default and the pages run under a Content-Security-Policy
that allows only the daemon's own script and style files: no inline script, no other origin.
A page says only the fixed texts of `MESSAGES`, and no link can choose which: what an action did
(an e-stop latched, released, an approval) is a one-time flash kept server-side for the session
that acted (`SessionStore.put_flash`; the URL carries its opaque id only), and the sign-in page
takes from its URL only the harmless codes of `LOGIN_CODES` (a wrong token, a full console, signed
out), never a status claim. A crafted link cannot put official-looking words (or a CSS class) on
the daemon's own page, nor make it say the e-stop was released while it is latched.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, get_args
from urllib.parse import urlencode

from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from starlette.responses import HTMLResponse

__all__ = ["LOGIN_CODES", "MESSAGES", "SECURITY_HEADERS", "MessageKind", "login_message", "login_query", "message_text",
           "page_headers", "render", "render_fragment"]

MessageKind = Literal["ok", "error"]
#: what a page may say after an action, by code (with an e-stop event number where the text has
#: ``{event}``): fixed texts and kinds, so nobody can put words on the daemon's own page; which one
#: a signed-in page shows is the session's flash, never the URL's choice
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
    "signed_out": ("ok", "Signed out."),
}
#: the codes the sign-in page shows from its URL (``?msg=CODE``): what went wrong with a sign-in,
#: or that one signed out; harmless in a forged link, since none of them claims a status
LOGIN_CODES = frozenset({"bad_token", "agent_token", "console_full", "signed_out"})

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


def message_text(code: str, event: int | None = None) -> tuple[str, MessageKind] | None:
    """`MESSAGES[code]`'s text (with `event` for ``{event}``) and kind; None for an unknown code
    or a text that needs an event number without one."""
    if code not in MESSAGES:
        return None
    kind, text = MESSAGES[code]
    if "{event}" in text:
        if not isinstance(event, int) or isinstance(event, bool):
            return None
        text = text.format(event=event)
    return text, kind


def login_query(code: str) -> str:
    """The query string that makes the sign-in page say `MESSAGES[code]` (one of `LOGIN_CODES`)."""
    if code not in LOGIN_CODES:
        raise KeyError(f"the sign-in page does not show {code!r} from its URL")
    return urlencode({"msg": code})


def login_message(query: Mapping[str, str]) -> tuple[str, MessageKind] | None:
    """The text and kind the sign-in page shows for its query string: one of `LOGIN_CODES`'s
    fixed texts; None for anything else (status codes included)."""
    code = query.get("msg")
    return message_text(code) if code in LOGIN_CODES else None


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
