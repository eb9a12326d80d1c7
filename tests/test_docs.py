"""The generated references (docs/policy.md, docs/tools.md) match the code, and server.json is valid.

The references are produced by scripts/gen_docs.py from the policy models and from the tools the
server really registers; when a model or a tool changes, these tests fail until the files are
regenerated, so the documentation can never silently drift from what the daemon enforces.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import pytest

import armwarden

ROOT = Path(__file__).resolve().parent.parent
REGENERATE_HINT = "docs are stale: run `python scripts/gen_docs.py` and commit the result"


def _load_generator():
    spec = importlib.util.spec_from_file_location("gen_docs", ROOT / "scripts" / "gen_docs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def gen_docs():
    return _load_generator()


def _first_difference(expected: str, actual: str) -> str:
    for number, (want, got) in enumerate(zip(expected.splitlines(), actual.splitlines(), strict=False), start=1):
        if want != got:
            return f"first difference at line {number}:\n  generated: {want!r}\n  on disk:   {got!r}"
    return f"generated {len(expected.splitlines())} lines, the file has {len(actual.splitlines())}"


def _assert_matches_generated(path: Path, expected: str) -> None:
    assert path.exists(), f"{path.relative_to(ROOT)} is missing; {REGENERATE_HINT}"
    actual = path.read_text(encoding="utf-8")
    assert actual == expected, f"{path.relative_to(ROOT)}: {REGENERATE_HINT}\n{_first_difference(expected, actual)}"


def test_policy_reference_is_up_to_date(gen_docs) -> None:
    _assert_matches_generated(gen_docs.POLICY_DOC, gen_docs.render_policy_doc())


def test_tools_reference_is_up_to_date(gen_docs) -> None:
    _assert_matches_generated(gen_docs.TOOLS_DOC, gen_docs.render_tools_doc())


def test_tools_reference_covers_every_tool_the_full_policy_registers(gen_docs) -> None:
    text = gen_docs.TOOLS_DOC.read_text(encoding="utf-8")
    from armwarden.policy import ALL_TOOLS

    missing = [tool for tool in ALL_TOOLS if f"### {tool}\n" not in text]
    assert not missing, f"docs/tools.md does not document {missing}"


def test_generation_is_deterministic(gen_docs) -> None:
    assert gen_docs.render_policy_doc() == gen_docs.render_policy_doc()


def test_server_json_parses_and_matches_the_package() -> None:
    document = json.loads((ROOT / "server.json").read_text(encoding="utf-8"))
    assert document["version"] == armwarden.__version__
    assert document["name"] == "io.github.armwarden/armwarden"
    assert re.fullmatch(r"[a-zA-Z0-9.-]+/[a-zA-Z0-9._-]+", document["name"])
    assert 1 <= len(document["description"]) <= 100  # the registry's limit
    # no package until a release exists; the schema and the release's entry: tests/packaging/test_server_json.py


@pytest.mark.parametrize("name", ["claude_desktop_config.json", "cursor_mcp.json", "mcp.json"])
def test_client_config_examples_launch_serve_on_stdio(name: str) -> None:
    document = json.loads((ROOT / "examples" / name).read_text(encoding="utf-8"))
    (server,) = document["mcpServers"].values()
    args = server["args"]
    assert args[0] == "serve"
    assert "--policy" in args and args[args.index("--policy") + 1].endswith("/robots/fr3/policy.yaml")
    assert "--audit-log" in args and args[args.index("--audit-log") + 1].startswith("/")
    assert "--transport" not in args or args[args.index("--transport") + 1] == "stdio"
