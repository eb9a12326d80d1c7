#!/usr/bin/env bash
# Create (or refresh) the project's virtual environment in .venv with everything the daemon and
# the tests need. Needs only python3 (>= 3.10) with pip and venv; uses uv for a fast install.
# Skips the install when pyproject.toml has not changed since the last successful one.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
VENV="${ARMWARDEN_VENV:-.venv}"
EXTRAS="${ARMWARDEN_EXTRAS:-dev,mujoco,can,image}"
stamp="$VENV/.armwarden-installed"
want="$(sha256sum pyproject.toml | cut -d' ' -f1) $EXTRAS"
if [ -x "$VENV/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  exit 0
fi
echo "bootstrap: installing armwarden[$EXTRAS] into $VENV" >&2
"$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check uv >&2
"$VENV/bin/python" -m uv pip install --quiet --python "$VENV/bin/python" -e ".[$EXTRAS]" >&2
echo "$want" > "$stamp"
