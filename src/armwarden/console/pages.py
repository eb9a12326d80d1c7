"""Server-rendered HTML: Jinja2 templates shipped in the package, autoescaped.

Every value on a page may carry text a model wrote (an e-stop reason, an audit detail), so the
environment escapes everything by default and the pages run under a Content-Security-Policy
that allows only the daemon's own script and style files: no inline script, no other origin.
"""

from __future__ import annotations

from typing import Any

from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from starlette.responses import HTMLResponse

__all__ = ["SECURITY_HEADERS", "page_headers", "render", "render_fragment"]

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
    `estop_url`: where the E-STOP button posts (the stop channel; None: the console's own route)."""
    html = _ENV.get_template(template).render({**_PAGE_DEFAULTS, **context})
    return HTMLResponse(html, status_code=status_code, headers=headers or SECURITY_HEADERS)


def render_fragment(template: str, **context: Any) -> HTMLResponse:
    """One live section (a `_name.html` template) for the page's refresh script."""
    return HTMLResponse(_ENV.get_template(template).render({**_PAGE_DEFAULTS, **context}), headers=SECURITY_HEADERS)
