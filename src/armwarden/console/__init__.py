"""The operator console: a small web UI served by the daemon, for the human beside the robot.

What it shows: the live robot state (joints against their limits, TCP, wrench, gripper, a top
and side view drawn by the plan preview renderer), the safety status (e-stop and its event
number, faults, force latch), the approval requests the server has asked about (summary,
findings, the plan's picture), and the audit tail with the chain's `audit verify` status.

What a human can do there: sign in with a token from the HTTP token file (an HttpOnly,
SameSite=Strict session cookie; a CSRF token on every POST), press E-STOP (on every page; it
posts to the independent stop channel with the session's ticket, so a busy event loop cannot
delay it; from this machine also without signing in, unless switched off), release the e-stop by typing the
event number shown (operators), and, when the policy's `approval.channel` is `url` or `both`,
approve or decline a motion (operators). Every action is audited with the token's name.

Where it is served: mounted at ``/console`` beside ``/mcp`` over HTTP (`transport/http.py`),
or on its own loopback port with ``--console-port`` on stdio. Server-rendered HTML (Jinja2,
autoescaped), one static script and one style sheet; no build step, nothing from another origin.

Modules: `sessions` (sign-in, CSRF), `feed` (what the pages read), `pages` (templates and
security headers), `core` (what every handler shares: settings, session look-up, audit,
refusals), `signin`, `views` (pages and live reads), `actions` (E-STOP, release, answer) and
`routes` (the routes and the ASGI app).
"""

from armwarden.console.actions import timed_estop
from armwarden.console.core import CONSOLE_PATH, ConsoleSettings, EStopHook
from armwarden.console.routes import build_console_app
from armwarden.console.sessions import SessionStore

__all__ = ["CONSOLE_PATH", "ConsoleSettings", "EStopHook", "SessionStore", "build_console_app", "timed_estop"]
