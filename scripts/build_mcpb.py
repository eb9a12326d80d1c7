"""Build the MCP Bundle `dist/armwarden.mcpb` that Claude Desktop installs with a double click.

    python scripts/build_mcpb.py [--out dist/armwarden.mcpb] [--require-validation]

The bundle is the `uv` server type of the MCPB spec (github.com/modelcontextprotocol/mcpb,
MANIFEST.md): it carries the source and pyproject.toml, not the dependencies, and `uv` installs
them on the user's machine at first start. `uv` is a server type of manifest version 0.4 (0.3's
are python, node and binary only), so the manifest says 0.4. Layout:

    manifest.json     server.type "uv"; mcp_config runs `uv run` on server/main.py
    pyproject.toml    the project's own: dependencies, extras, package data
    README.md         pyproject's `readme` (the build needs it)
    server/main.py    scripts/mcpb_launcher.py: the user's settings (environment) → `armwarden serve`
    src/armwarden/    the package, without caches

When the official `mcpb` CLI is installed (`npm ci --prefix tools/mcpb`, done by
scripts/bootstrap.sh where npm exists), the manifest is validated with `mcpb validate` before the
archive is written; `--require-validation` makes a missing CLI an error. The archive is written
with fixed timestamps and sorted entries, so the same tree gives the same bytes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
MCPB_CLI = REPO / "tools" / "mcpb" / "node_modules" / ".bin" / "mcpb"
DEFAULT_OUT = REPO / "dist" / "armwarden.mcpb"
#: the MCPB manifest version that has the `uv` server type
MANIFEST_VERSION = "0.4"
#: 1980-01-01, the earliest time a zip entry can carry: reproducible archives
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)
_NOT_SHIPPED = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")


def _version() -> str:
    """The checkout's version (`armwarden.__version__`, which pyproject.toml repeats)."""
    sys.path.insert(0, str(REPO / "src"))
    try:
        from armwarden import __version__
    finally:
        sys.path.pop(0)
    return __version__


def manifest(version: str) -> dict[str, Any]:
    """The bundle's manifest.json: the user's settings reach the launcher as environment variables.

    Every optional setting has a default: the host (mcpb's `getMcpConfigForManifest`) leaves
    `${user_config.X}` literal in the environment when X has neither a value nor a default, and
    the launcher and the daemon refuse such a placeholder. An empty default is an empty
    variable, which the launcher reads as "the daemon's default"."""
    return {
        "manifest_version": MANIFEST_VERSION,
        "name": "armwarden",
        "display_name": "ArmWarden",
        "version": version,
        "description": "Safety-first MCP server for robot arms: plan, preview and execute under server-enforced limits",
        "long_description": (
            "ArmWarden lets an agent drive a robot arm through a small, fixed set of skill tools while the "
            "server, not the model, enforces every limit: workspace and keep-out zones, joint and speed "
            "limits, human approval of motions, an e-stop and a hash-chained audit log. The default backend "
            "is a simulated Franka FR3 that needs no hardware.\n\n"
            "Not certified functional safety: the robot's own safety system and a hardware e-stop are the "
            "real safety layer. The first start installs the Python dependencies with uv (a few minutes)."
        ),
        "author": {"name": "ArmWarden developers"},
        "repository": {"type": "git", "url": "https://github.com/armwarden/armwarden"},
        "license": "Apache-2.0",
        "keywords": ["robotics", "robot-arm", "safety", "franka", "mujoco"],
        "server": {
            "type": "uv",
            "entry_point": "server/main.py",
            "mcp_config": {
                "command": "uv",
                "args": [
                    "run", "--directory", "${__dirname}", "--extra", "mujoco", "--extra", "can",
                    "python", "${__dirname}/server/main.py",
                ],
                "env": {
                    "ARMWARDEN_POLICY": "${user_config.policy}",
                    "ARMWARDEN_BACKEND": "${user_config.backend}",
                    "ARMWARDEN_BACKEND_CONFIG": "${user_config.backend_config}",
                    "ARMWARDEN_AUDIT_LOG": "${user_config.audit_log}",
                    "ARMWARDEN_AUDIT_KEY": "${user_config.audit_key}",
                },
            },
        },
        "compatibility": {
            # POSIX only: SIGUSR1 is the out-of-band e-stop, and the token and audit files use POSIX locks
            "platforms": ["darwin", "linux"],
            "runtimes": {"python": ">=3.10"},
        },
        "user_config": {
            "policy": {
                "type": "file",
                "title": "Safety policy",
                "description": "Policy YAML (check it with `armwarden check-policy FILE`). Empty: the bundled Franka FR3 policy.",
                "default": "",
                "required": False,
            },
            "backend": {
                "type": "string",
                "title": "Robot backend",
                "description": "fake (a simulated FR3, no hardware), mujoco or can. ros2 needs a ROS 2 environment: "
                               "see docs/packaging.md.",
                "default": "fake",
                "required": False,
            },
            "backend_config": {
                "type": "file",
                "title": "Backend configuration",
                "description": "The backend's options YAML (e.g. examples/mujoco_scene.yaml). Empty: the backend's defaults.",
                "default": "",
                "required": False,
            },
            "audit_log": {
                "type": "string",
                "title": "Audit log",
                "description": "Append-only, hash-chained audit log (JSONL); an absolute path. "
                               "`armwarden audit verify FILE` checks it. Empty: ~/armwarden-audit.jsonl.",
                # not "${HOME}/…": the host substitutes ${HOME} before the settings, so it would stay literal;
                # the launcher puts an empty one in the home directory
                "default": "",
                "required": False,
            },
            "audit_key": {
                "type": "string",
                "title": "Audit HMAC key",
                "description": "Optional key for the audit log's hash chain (keep it to verify the log later). "
                               "Empty: a plain SHA-256 chain.",
                "sensitive": True,
                "default": "",
                "required": False,
            },
        },
    }


def stage(root: Path, version: str) -> Path:
    """Lay the bundle's files out under `root/armwarden` and return that directory."""
    bundle = root / "armwarden"
    bundle.mkdir()
    shutil.copy2(REPO / "pyproject.toml", bundle)
    shutil.copy2(REPO / "README.md", bundle)
    (bundle / "server").mkdir()
    shutil.copy2(REPO / "scripts" / "mcpb_launcher.py", bundle / "server" / "main.py")
    shutil.copytree(REPO / "src" / "armwarden", bundle / "src" / "armwarden", ignore=_NOT_SHIPPED)
    (bundle / "manifest.json").write_text(json.dumps(manifest(version), indent=2) + "\n", encoding="utf-8")
    return bundle


def validate(bundle: Path, cli: Path) -> None:
    """`mcpb validate` on the staged manifest; SystemExit with its report when it fails."""
    result = subprocess.run([str(cli), "validate", str(bundle / "manifest.json")],
                            capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise SystemExit(f"build_mcpb: mcpb validate refused the manifest:\n{result.stdout}{result.stderr}")


def pack(bundle: Path, out: Path) -> list[str]:
    """Zip `bundle` into `out` (sorted entries, fixed times, 0644); returns the entry names."""
    names = sorted(path.relative_to(bundle).as_posix() for path in bundle.rglob("*") if path.is_file())
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    with zipfile.ZipFile(partial, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        for name in names:
            info = zipfile.ZipInfo(name, date_time=_ZIP_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o100644 << 16  # a regular file, rw-r--r--
            info.create_system = 3  # unix, so that the mode above is read
            archive.writestr(info, (bundle / name).read_bytes())
    partial.replace(out)
    return names


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Build the MCP Bundle dist/armwarden.mcpb (server type uv).")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"where the bundle goes (default {DEFAULT_OUT})")
    parser.add_argument("--mcpb", type=Path, default=MCPB_CLI, help="the mcpb CLI (default: tools/mcpb's, from npm ci)")
    parser.add_argument("--require-validation", action="store_true", help="fail when the mcpb CLI is not installed")
    args = parser.parse_args(argv)
    version = _version()
    with tempfile.TemporaryDirectory(prefix="armwarden-mcpb-") as tmp:
        bundle = stage(Path(tmp), version)
        if args.mcpb.is_file():
            validate(bundle, args.mcpb)
            print(f"build_mcpb: manifest valid ({args.mcpb} validate)", file=sys.stderr)
        elif args.require_validation:
            print(f"build_mcpb: no mcpb CLI at {args.mcpb}: run `npm ci --prefix tools/mcpb`", file=sys.stderr)
            return 1
        else:
            print(f"build_mcpb: manifest NOT validated: no mcpb CLI at {args.mcpb} (npm ci --prefix tools/mcpb)",
                  file=sys.stderr)
        names = pack(bundle, args.out)
    digest = hashlib.sha256(args.out.read_bytes()).hexdigest()
    print(f"{args.out}: armwarden {version}, {len(names)} files, {args.out.stat().st_size} bytes, sha256 {digest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
