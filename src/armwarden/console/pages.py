"""Server-rendered HTML: Jinja2 templates shipped in the package, autoescaped.

Every value on a page may carry text a model wrote (an e-stop reason, an audit detail), so the
environment escapes everything by default and the pages run under a Content-Security-Policy
that allows only the daemon's own script and style files: no inline script, no other origin.
"""

from __future__ import annotations

from typing import Any

from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from starlette.responses import HTMLResponse

__all__ = ["SECURITY_HEADERS", "render", "render_fragment"]

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

_ENV = Environment(
    loader=PackageLoader("armwarden.console", "templates"),
    autoescape=select_autoescape(default=True, default_for_string=True),
    undefined=StrictUndefined,  # a missing value is a bug, not an empty string
    trim_blocks=True,
    lstrip_blocks=True,
)

_PAGE_DEFAULTS: dict[str, Any] = {"session": None, "message": None, "message_kind": "ok", "title": "console"}


def render(template: str, *, status_code: int = 200, **context: Any) -> HTMLResponse:
    """A whole page (`template` extends base.html); `base` (the console's path) must be given."""
    html = _ENV.get_template(template).render({**_PAGE_DEFAULTS, **context})
    return HTMLResponse(html, status_code=status_code, headers=SECURITY_HEADERS)


def render_fragment(template: str, **context: Any) -> HTMLResponse:
    """One live section (a `_name.html` template) for the page's refresh script."""
    return HTMLResponse(_ENV.get_template(template).render({**_PAGE_DEFAULTS, **context}), headers=SECURITY_HEADERS)
