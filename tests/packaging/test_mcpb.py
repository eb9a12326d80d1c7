"""The MCP Bundle scripts/build_mcpb.py builds: valid for the official `mcpb` CLI, complete, and served.

The CLI is `@anthropic-ai/mcpb` from npm, pinned in tools/mcpb/package-lock.json and installed at
set-up (`npm ci --prefix tools/mcpb`, scripts/bootstrap.sh), never at test time. The same package
holds the host code that fills a bundle's `mcp_config` in from the user's settings
(`dist/shared/config.js`, `getMcpConfigForManifest`, which Claude Desktop shares): the served
tests run it with node, so the environment is the one a host hands over, not this file's idea of
it. Missing (CLI or node), these tests fail under CI (`CI` or ARMWARDEN_REQUIRE_MCPB set: .ci/run)
and are skipped with the install hint otherwise. The launcher's own tests
(tests/packaging/test_mcpb_launcher.py) need no CLI.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any, NoReturn

import anyio
import pytest
from mcp import Client, StdioServerParameters

from armwarden.audit import verify_file
from tests.helpers import BUNDLED_TOOL_COUNT, REPO

MCPB = REPO / "tools" / "mcpb" / "node_modules" / ".bin" / "mcpb"
#: the mcpb host code that fills `mcp_config` in (variables, user_config defaults, the user's settings)
MCPB_HOST_CONFIG = REPO / "tools" / "mcpb" / "node_modules" / "@anthropic-ai" / "mcpb" / "dist" / "shared" / "config.js"
BUILD = REPO / "scripts" / "build_mcpb.py"
REQUIRE_ENV = "ARMWARDEN_REQUIRE_MCPB"


def _missing(message: str) -> NoReturn:
    """Fail under CI (the bundle must be checked there), skip with the install hint elsewhere."""
    if os.environ.get(REQUIRE_ENV) or os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


def _mcpb() -> Path:
    if MCPB.is_file() and shutil.which("node") is not None:  # the CLI is a node script
        return MCPB
    _missing(f"no mcpb CLI at {MCPB} or no node on PATH: run `npm ci --prefix tools/mcpb` (node and npm needed)")


#: node: `getMcpConfigForManifest` on a manifest file with the user's settings (JSON), as a host
#: calls it; prints the filled-in mcp_config (null when the host would not start the server)
_HOST_FILLS_IN = """
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";
const [configJs, manifestPath, userConfig, extensionPath, home] = process.argv.slice(1);
const { getMcpConfigForManifest } = await import(pathToFileURL(configJs).href);
const config = await getMcpConfigForManifest({
  manifest: JSON.parse(readFileSync(manifestPath, "utf8")), extensionPath, pathSeparator: "/",
  systemDirs: { HOME: home, DESKTOP: `${home}/Desktop`, DOCUMENTS: `${home}/Documents`, DOWNLOADS: `${home}/Downloads` },
  userConfig: JSON.parse(userConfig), logger: console,
});
console.log(JSON.stringify(config ?? null));
"""


def _as_the_mcpb_host_fills_it(unpacked: Path, user_config: dict[str, str], home: Path) -> dict[str, Any]:
    """The bundle's `mcp_config` as the official host code fills it in for `user_config` (the
    settings the user changed; the others keep the manifest's defaults), at home directory `home`."""
    node = shutil.which("node")
    if node is None or not MCPB_HOST_CONFIG.is_file():
        _missing(f"no node or no mcpb host code at {MCPB_HOST_CONFIG}: install node, run `npm ci --prefix tools/mcpb`")
    result = _run(node, "--input-type=module", "-e", _HOST_FILLS_IN, MCPB_HOST_CONFIG, unpacked / "manifest.json",
                  json.dumps(user_config), unpacked, home)
    assert result.returncode == 0, result.stdout + result.stderr
    config = json.loads(result.stdout)
    assert config is not None, f"the host would not start the server: {result.stderr}"
    return config


def _run(*argv: str | Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(part) for part in argv], capture_output=True, text=True, timeout=timeout, check=False)


def _package_files(package: Path) -> set[str]:
    return {path.relative_to(package.parent).as_posix() for path in package.rglob("*")
            if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc"}


@pytest.fixture(scope="module")
def bundle(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, set[str]]:
    """The bundle the script builds (validating it with the CLI), and the package's files before the build."""
    cli = _mcpb()
    before = _package_files(REPO / "src" / "armwarden")
    out = tmp_path_factory.mktemp("bundle") / "armwarden.mcpb"
    result = _run(sys.executable, BUILD, "--out", out, "--mcpb", cli, "--require-validation")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "manifest valid" in result.stderr
    return out, before


@pytest.fixture(scope="module")
def unpacked(bundle: tuple[Path, set[str]], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundle as the official CLI unpacks it (what a host installs)."""
    target = tmp_path_factory.mktemp("unpacked")
    result = _run(_mcpb(), "unpack", bundle[0], target)
    assert result.returncode == 0, result.stdout + result.stderr
    return target


def _manifest(unpacked: Path) -> dict[str, Any]:
    return json.loads((unpacked / "manifest.json").read_text(encoding="utf-8"))


def test_mcpb_validate_passes_on_the_built_bundles_manifest(unpacked: Path) -> None:
    result = _run(_mcpb(), "validate", unpacked / "manifest.json")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Manifest schema validation passes" in result.stdout


def test_mcpb_validate_refuses_the_uv_server_type_under_manifest_0_3(unpacked: Path, tmp_path: Path) -> None:
    """Why the manifest says 0.4: `uv` is not a server type of 0.3 (and the check above is not vacuous)."""
    manifest = {**_manifest(unpacked), "manifest_version": "0.3"}
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(manifest), encoding="utf-8")
    result = _run(_mcpb(), "validate", path)
    assert result.returncode == 1
    assert "server.type" in result.stdout


def test_mcpb_info_reads_the_bundle(bundle: tuple[Path, set[str]]) -> None:
    result = _run(_mcpb(), "info", bundle[0])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "File: armwarden.mcpb" in result.stdout


def test_bundle_holds_the_source_pyproject_and_launcher(bundle: tuple[Path, set[str]], unpacked: Path) -> None:
    _, package_files = bundle
    shipped = {path.relative_to(unpacked).as_posix() for path in unpacked.rglob("*") if path.is_file()}
    assert {"manifest.json", "pyproject.toml", "README.md", "server/main.py"} <= shipped
    assert sorted({f"src/{name}" for name in package_files} - shipped) == []
    assert [name for name in shipped if "__pycache__" in name or name.endswith((".pyc", ".egg-info"))] == []
    assert (unpacked / "server" / "main.py").read_bytes() == (REPO / "scripts" / "mcpb_launcher.py").read_bytes()


def test_manifest_is_the_uv_server_type_at_the_projects_version(unpacked: Path) -> None:
    manifest = _manifest(unpacked)
    project_version = re.search(r'^version = "([^"]+)"$', (unpacked / "pyproject.toml").read_text(encoding="utf-8"), re.M)
    assert project_version is not None
    assert manifest["manifest_version"] == "0.4"
    assert manifest["server"]["type"] == "uv"
    assert manifest["version"] == project_version.group(1)
    assert (unpacked / manifest["server"]["entry_point"]).is_file()


def test_every_user_setting_reaches_the_server_and_only_the_audit_key_is_secret(unpacked: Path) -> None:
    manifest = _manifest(unpacked)
    settings = manifest["user_config"]
    used = set(re.findall(r"\$\{user_config\.(\w+)\}", json.dumps(manifest["server"]["mcp_config"])))
    assert used == set(settings) == {"policy", "backend", "backend_config", "audit_log", "audit_key"}
    assert [key for key, option in settings.items() if option.get("sensitive")] == ["audit_key"]
    assert manifest["server"]["mcp_config"]["env"]["ARMWARDEN_AUDIT_KEY"] == "${user_config.audit_key}"


async def _serve_the_bundle(unpacked: Path, config: dict[str, Any], cwd: Path, home: Path) -> tuple[int, Any]:
    """Serve the bundle as `config` (filled in by the host) says, through its launcher and its own
    source; returns the number of tools and the robot state's structured content.

    Python here stands in for `uv run` (which would install the dependencies from the network); the
    source comes from the bundle alone (PYTHONPATH)."""
    # numba would compile the envelope's kernels afresh for this new path (about 25 s); they run as plain Python
    env = {**config["env"], "PYTHONPATH": str(unpacked / "src"), "NUMBA_DISABLE_JIT": "1", "HOME": str(home)}
    probe = await anyio.run_process([sys.executable, "-c", "import armwarden; print(armwarden.__file__)"],
                                    env={**os.environ, **env}, cwd=cwd)
    assert probe.stdout.decode().strip() == str(unpacked / "src" / "armwarden" / "__init__.py")  # the bundle's, not the checkout's
    entry = config["args"][-1]
    assert entry == str(unpacked / "server" / "main.py")
    params = StdioServerParameters(command=sys.executable, args=[entry, "--log-level", "WARNING"], env=env, cwd=str(cwd))
    with anyio.fail_after(120):
        async with Client(params) as client:
            tools = await client.list_tools()
            state = await client.call_tool("get_robot_state", {})
            assert not state.is_error
            return len(tools.tools), state.structured_content


def _startup_record(audit: Path) -> dict[str, Any]:
    return next(record for line in audit.read_text(encoding="utf-8").splitlines()
                if (record := json.loads(line)).get("event") == "startup")


@pytest.mark.anyio
async def test_bundle_serves_every_setting_the_user_fills_in(unpacked: Path, tmp_path: Path) -> None:
    """Every setting filled in, the environment filled in by the official host code: the bundle's
    launcher serves its own source with the user's policy, backend, backend options, audit log and key."""
    home, policy, options, audit = tmp_path / "home", tmp_path / "policy.yaml", tmp_path / "fake.yaml", tmp_path / "audit.jsonl"
    home.mkdir()
    shutil.copy(REPO / "examples" / "tighter_policy.yaml", policy)
    options.write_text("wrench: false\n", encoding="utf-8")  # the default provides one: seen in the state
    settings = {"policy": str(policy), "backend": "fake", "backend_config": str(options), "audit_log": str(audit),
                "audit_key": "k-e-y"}
    config = _as_the_mcpb_host_fills_it(unpacked, settings, home)
    tool_count, state = await _serve_the_bundle(unpacked, config, tmp_path, home)
    assert tool_count == BUNDLED_TOOL_COUNT
    assert state["wrench"] is None
    assert verify_file(audit, b"k-e-y").ok
    assert not verify_file(audit).ok
    startup = _startup_record(audit)
    assert startup["extra"]["policy"] == str(policy)
    assert "with the fake backend" in startup["detail"]


def test_the_mcpb_host_leaves_no_placeholder_for_a_setting_the_user_left_untouched(unpacked: Path, tmp_path: Path) -> None:
    """A fresh install (no setting changed): a setting without a default would stay `${user_config.X}`
    in the environment, which the launcher and the daemon refuse, so the bundle would never start."""
    env = _as_the_mcpb_host_fills_it(unpacked, {}, tmp_path)["env"]
    assert {name: value for name, value in env.items() if "${user_config." in value} == {}
    assert env["ARMWARDEN_POLICY"] == env["ARMWARDEN_BACKEND_CONFIG"] == env["ARMWARDEN_AUDIT_KEY"] == ""


@pytest.mark.anyio
async def test_bundle_serves_on_a_fresh_install_with_the_audit_log_in_the_home_directory(unpacked: Path, tmp_path: Path) -> None:
    """No setting changed, the environment filled in by the official host code: every variable is
    expanded (the host substitutes `${HOME}` before the settings, so a default reading `${HOME}/…`
    would reach the launcher literally), the bundle serves the bundled policy on the fake backend,
    and the audit log, unkeyed, is `~/armwarden-audit.jsonl`, not in the host's working directory."""
    home, cwd = tmp_path / "home", tmp_path / "cwd"
    home.mkdir()
    cwd.mkdir()
    config = _as_the_mcpb_host_fills_it(unpacked, {}, home)
    assert {name: value for name, value in config["env"].items() if "$" in value} == {}
    tool_count, state = await _serve_the_bundle(unpacked, config, cwd, home)
    assert tool_count == BUNDLED_TOOL_COUNT
    assert state["wrench"] is not None  # the fake backend's default options
    audit = home / "armwarden-audit.jsonl"
    assert verify_file(audit).ok
    startup = _startup_record(audit)
    assert startup["extra"]["policy"] == "bundled fr3"
    assert "with the fake backend" in startup["detail"]
    assert list(cwd.iterdir()) == []
