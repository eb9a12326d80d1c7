"""`armwarden serve` as an MCP Bundle starts it: the bundle's `server/main.py` (scripts/build_mcpb.py copies it).

The host (Claude Desktop) hands the user's settings over as environment variables
(`mcp_config.env` in the bundle's manifest.json), not as arguments: a setting left empty then
falls back to the daemon's own default instead of becoming an empty `--policy ""`, and the same
file works whether the host runs `mcp_config` or runs this entry point itself. A value still
reading `${...}` is a placeholder the host did not fill in: refused, never passed on as a path.
The audit key (`ARMWARDEN_AUDIT_KEY`) is read by the daemon itself, which refuses a placeholder too.

One empty setting does not keep the daemon's default: the audit log. The daemon's is relative to
its working directory, which the host chooses (often `/`, not writable, or a different one each
version), so the launcher puts it at `~/armwarden-audit.jsonl` and says so on stderr. The manifest
cannot say `${HOME}/armwarden-audit.jsonl` itself: mcpb's host code substitutes `${HOME}` before
it inserts the settings' values, so a default reading `${HOME}` arrives unexpanded.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping, Sequence

#: environment variable → `armwarden serve` option, in the order they are passed
SETTINGS = (
    ("ARMWARDEN_POLICY", "--policy"),
    ("ARMWARDEN_BACKEND", "--backend"),
    ("ARMWARDEN_BACKEND_CONFIG", "--backend-config"),
    ("ARMWARDEN_AUDIT_LOG", "--audit-log"),
)
AUDIT_LOG_ENV = "ARMWARDEN_AUDIT_LOG"
#: the audit log's file name in the home directory when the setting is empty
AUDIT_LOG_NAME = "armwarden-audit.jsonl"
EXIT_REFUSED = 2  # the daemon's "refused to start"


class RefusedSetting(ValueError):
    """A setting the launcher will not hand to the daemon: it refuses to start instead."""


class UnfilledSetting(RefusedSetting):
    """A setting still holds the host's placeholder."""


def default_audit_log(environ: Mapping[str, str]) -> str:
    """`~/armwarden-audit.jsonl` for the home directory of `environ` (HOME, else the user
    database, as `expanduser` does); refused when there is no absolute home directory."""
    home = environ.get("HOME", "").strip() or os.path.expanduser("~")
    if not os.path.isabs(home):
        raise RefusedSetting(
            f"{AUDIT_LOG_ENV} is empty and there is no home directory to put the audit log in "
            f"(HOME is {home!r}): set the audit log in the extension's settings"
        )
    return os.path.join(home, AUDIT_LOG_NAME)


def serve_arguments(environ: Mapping[str, str], extra: Sequence[str] = (),
                    say: Callable[[str], None] = lambda _note: None) -> list[str]:
    """`armwarden serve` with an option for each setting that is set and not empty, then `extra`;
    an empty audit log becomes `~/armwarden-audit.jsonl`, which `say` is told."""
    arguments = ["serve"]
    for name, option in SETTINGS:
        value = environ.get(name, "").strip()
        if value.startswith(("${", "$(")):
            raise UnfilledSetting(
                f"{name} is {value!r}, a placeholder the MCP host did not fill in: set it in the "
                f"extension's settings, or leave it empty for the default"
            )
        if not value and name == AUDIT_LOG_ENV:
            value = default_audit_log(environ)
            say(f"{AUDIT_LOG_ENV} is empty (no audit log in the extension's settings): the audit log is {value}")
        if value:
            arguments += [option, value]
    return [*arguments, *extra]


def _to_stderr(note: str) -> None:
    print(f"armwarden: {note}", file=sys.stderr, flush=True)


def main() -> int:
    try:
        arguments = serve_arguments(os.environ, sys.argv[1:], say=_to_stderr)
    except RefusedSetting as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    from armwarden.cli import main as armwarden_main  # after the check: a refusal needs no robot stack

    return armwarden_main(arguments)


if __name__ == "__main__":
    sys.exit(main())
