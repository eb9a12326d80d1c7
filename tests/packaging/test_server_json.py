"""server.json, the MCP Registry entry: valid against the registry's schema, honest about installing.

The schema is the registry's own file (tests/data/mcp-registry, byte-for-byte, pinned by its
SHA-256), so the check runs offline. No release exists on PyPI yet, so server.json names no package
(a `pypi` entry would advertise `uvx armwarden`, which installs nothing) and points to the
repository's install instructions instead; docs/packaging.md holds the package entry to add when
the first release is published.
"""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

import pytest
from jsonschema import Draft7Validator

from tests.helpers import REPO

SCHEMA = REPO / "tests" / "data" / "mcp-registry" / "server.schema.2025-12-11.json"
SCHEMA_SHA256 = "3fba09590c99f61735d234822279f4223fab9e300c0a81e81c91ab62a4114de0"
REPOSITORY = "https://github.com/armwarden/armwarden"


def _server() -> dict[str, Any]:
    return json.loads((REPO / "server.json").read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def validator() -> Draft7Validator:
    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    return Draft7Validator(schema, format_checker=Draft7Validator.FORMAT_CHECKER)


def test_schema_copy_is_the_registrys_file_unchanged() -> None:
    assert hashlib.sha256(SCHEMA.read_bytes()).hexdigest() == SCHEMA_SHA256


def test_server_json_names_the_schema_it_is_checked_against() -> None:
    assert _server()["$schema"] == json.loads(SCHEMA.read_text(encoding="utf-8"))["$id"]


def test_server_json_validates_against_the_registry_schema(validator: Draft7Validator) -> None:
    errors = [f"{'/'.join(map(str, error.absolute_path)) or '/'}: {error.message}" for error in validator.iter_errors(_server())]
    assert errors == []


def test_the_schema_refuses_a_description_over_100_characters(validator: Draft7Validator) -> None:
    """The check above can fail: the registry's length limit is enforced here too."""
    assert not validator.is_valid({**_server(), "description": "x" * 101})


def test_server_json_version_is_the_projects() -> None:
    project = re.search(r'^version = "([^"]+)"$', (REPO / "pyproject.toml").read_text(encoding="utf-8"), re.M)
    assert project is not None and _server()["version"] == project.group(1)


def test_server_json_name_is_the_one_the_readme_claims() -> None:
    """The registry checks a PyPI package's ownership by this marker in its README (the long description)."""
    assert f"mcp-name: {_server()['name']}" in (REPO / "README.md").read_text(encoding="utf-8")


def test_server_json_says_how_to_install_from_the_repository_until_a_release_exists() -> None:
    server = _server()
    assert "packages" not in server  # nothing is on PyPI yet: `uvx armwarden` would install nothing
    assert server["repository"]["url"] == REPOSITORY
    prefix = f"{REPOSITORY}/blob/main/"
    assert server["websiteUrl"].startswith(prefix)
    instructions = REPO / server["websiteUrl"][len(prefix):]
    assert "bash scripts/run.sh" in instructions.read_text(encoding="utf-8")
    assert "bash scripts/run.sh" in server["_meta"]["io.modelcontextprotocol.registry/publisher-provided"]["installFromRepository"]


def test_the_package_entry_docs_give_for_the_first_release_validates(validator: Draft7Validator) -> None:
    """docs/packaging.md's `packages` block, added to today's server.json, is a valid entry too."""
    docs = (REPO / "docs" / "packaging.md").read_text(encoding="utf-8")
    block = re.search(r"```json\n(\"packages\": \[.*?\])\n```", docs, re.S)
    assert block is not None
    packages = json.loads("{" + block.group(1) + "}")["packages"]
    (package,) = packages
    assert (package["registryType"], package["identifier"], package["version"]) == ("pypi", "armwarden", _server()["version"])
    assert package["transport"] == {"type": "stdio"}
    assert package["packageArguments"][0] == {"type": "positional", "value": "serve"}
    (key,) = [v for v in package["environmentVariables"] if v["name"] == "ARMWARDEN_AUDIT_KEY"]
    assert key["isSecret"] is True and key["isRequired"] is False
    errors = [error.message for error in validator.iter_errors({**_server(), "packages": packages})]
    assert errors == []
