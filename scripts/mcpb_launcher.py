"""`armwarden serve` as an MCP Bundle starts it: the bundle's `server/main.py` (scripts/build_mcpb.py copies it).

The host (Claude Desktop) hands the user's settings over as environment variables
(`mcp_config.env` in the bundle's manifest.json), not as arguments: a setting left empty then
falls back to the daemon's own default instead of becoming an empty `--policy ""`, and the same
file works whether the host runs `mcp_config` or runs this entry point itself. A value still
reading `${...}` is a placeholder the host did not fill in: refused, never passed on as a path.
The audit key (`ARMWARDEN_AUDIT_KEY`) is read by the daemon itself, which refuses a placeholder too.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence

#: environment variable → `armwarden serve` option, in the order they are passed
SETTINGS = (
    ("ARMWARDEN_POLICY", "--policy"),
    ("ARMWARDEN_BACKEND", "--backend"),
    ("ARMWARDEN_BACKEND_CONFIG", "--backend-config"),
    ("ARMWARDEN_AUDIT_LOG", "--audit-log"),
)
EXIT_REFUSED = 2  # the daemon's "refused to start"


class UnfilledSetting(ValueError):
    """A setting still holds the host's placeholder."""


def serve_arguments(environ: Mapping[str, str], extra: Sequence[str] = ()) -> list[str]:
    """`armwarden serve` with an option for each setting that is set and not empty, then `extra`."""
    arguments = ["serve"]
    for name, option in SETTINGS:
        value = environ.get(name, "").strip()
        if not value:
            continue
        if value.startswith(("${", "$(")):
            raise UnfilledSetting(
                f"{name} is {value!r}, a placeholder the MCP host did not fill in: set it in the "
                f"extension's settings, or leave it empty for the default"
            )
        arguments += [option, value]
    return [*arguments, *extra]


def main() -> int:
    try:
        arguments = serve_arguments(os.environ, sys.argv[1:])
    except UnfilledSetting as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    from armwarden.cli import main as armwarden_main  # after the check: a refusal needs no robot stack

    return armwarden_main(arguments)


if __name__ == "__main__":
    sys.exit(main())
