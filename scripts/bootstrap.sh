#!/usr/bin/env bash
# Create (or refresh) the project's virtual environment in .venv with everything the daemon and
# the tests need. Needs only python3 (>= 3.10) with pip and venv; uses uv for a fast install.
# Skips the install when pyproject.toml (and the constraints file, if any) has not changed since
# the last successful one.
#
#   ARMWARDEN_VENV         where the venv goes (default .venv)
#   ARMWARDEN_EXTRAS       the extras to install (default dev,mujoco,can,image)
#   ARMWARDEN_CONSTRAINTS  an optional pip constraints file, e.g. constraints/ros.txt for the ROS
#                          venv scripts/test.sh builds (.venv-ros, extras dev,can,ros)
#   ARMWARDEN_NO_INSTALL   1: install nothing (no pip, no apt-get, no network); fail (exit 3) if the
#                          venv is missing or out of date (tests that run run.sh as a user would)
#
# The operator console's browser tests (tests/console) drive Debian's chromium through
# chromium-driver: installed here with apt-get where that can be done (root, or sudo without a
# password); otherwise the tests say what to install (and fail in CI, .ci/run).
set -euo pipefail
cd "$(dirname "$0")/.."
no_install="${ARMWARDEN_NO_INSTALL:-0}"
if [ "$no_install" != 1 ] && { [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; } \
    && command -v apt-get >/dev/null 2>&1; then
  as_root=()
  if [ "$(id -u)" != 0 ]; then as_root=(sudo -n); fi
  if [ "${#as_root[@]}" = 0 ] || sudo -n true 2>/dev/null; then
    echo "bootstrap: installing chromium and chromium-driver (browser tests of the operator console)" >&2
    "${as_root[@]}" apt-get install -y -qq chromium chromium-driver >&2 \
      || { "${as_root[@]}" apt-get update -qq >&2 && "${as_root[@]}" apt-get install -y -qq chromium chromium-driver >&2; } \
      || echo "bootstrap: could not install chromium; the console's browser tests will say so" >&2
  fi
fi
PYTHON="${PYTHON:-python3}"
VENV="${ARMWARDEN_VENV:-.venv}"
EXTRAS="${ARMWARDEN_EXTRAS:-dev,mujoco,can,image}"
CONSTRAINTS="${ARMWARDEN_CONSTRAINTS:-}"
stamp="$VENV/.armwarden-installed"
want="$(sha256sum pyproject.toml | cut -d' ' -f1) $EXTRAS"
constrain=()
if [ -n "$CONSTRAINTS" ]; then
  want="$want $CONSTRAINTS=$(sha256sum "$CONSTRAINTS" | cut -d' ' -f1)"
  constrain=(-c "$CONSTRAINTS")
fi
if ! { [ -x "$VENV/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; }; then
  if [ "$no_install" = 1 ]; then
    echo "bootstrap: $VENV is missing or out of date and ARMWARDEN_NO_INSTALL=1 forbids installing" >&2
    exit 3
  fi
  echo "bootstrap: installing armwarden[$EXTRAS] into $VENV${CONSTRAINTS:+ (constraints: $CONSTRAINTS)}" >&2
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check uv >&2
  "$VENV/bin/python" -m uv pip install --quiet --python "$VENV/bin/python" "${constrain[@]}" -e ".[$EXTRAS]" >&2
  echo "$want" > "$stamp"
fi
# Compile the envelope's numba kernels into their on-disk cache now (about 30 s on a fresh machine,
# well under a second once cached), so that neither the first daemon start nor a test pays it
# while a backend's real-time thread or a start-up deadline is waiting.
"$VENV/bin/python" -c "import armwarden.safety.kernel.driver" >&2
# The official MCP Bundle CLI, `mcpb` (tools/mcpb: @anthropic-ai/mcpb pinned by its
# package-lock.json): tests/packaging validate the bundle scripts/build_mcpb.py builds with it.
# Installed only where npm exists; without it those tests say what to install (and fail in CI).
mcpb_stamp=tools/mcpb/node_modules/.armwarden-installed
mcpb_want="$(sha256sum tools/mcpb/package-lock.json | cut -d' ' -f1)"
if [ "${ARMWARDEN_NO_INSTALL:-0}" != 1 ] && command -v npm >/dev/null 2>&1 \
    && ! { [ -f "$mcpb_stamp" ] && [ "$(cat "$mcpb_stamp")" = "$mcpb_want" ]; }; then
  echo "bootstrap: installing the mcpb CLI into tools/mcpb (npm ci)" >&2
  if npm ci --prefix tools/mcpb --no-audit --no-fund --loglevel=error >&2; then
    echo "$mcpb_want" > "$mcpb_stamp"
  else
    echo "bootstrap: npm ci --prefix tools/mcpb failed; the bundle's tests will say what to install" >&2
  fi
fi
