"""docs/architecture.md names real code: every function, method or class in the "Where each limit
is enforced" table exists where the table says, so a newcomer who follows it lands on the check."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src" / "armwarden"
#: names in the table that are not ArmWarden's own code (the SDK's, pydantic's)
EXTERNAL = {"RequestStateBoundary", "Field"}
IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)?$")


def enforced_in_cells() -> list[str]:
    """Every backticked token of the table's "enforced in" column."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text.split("## Where each limit is enforced", 1)[1].split("\n## ", 1)[0]
    tokens: list[str] = []
    for row in section.splitlines():
        cells = row.split("|")
        if len(cells) < 5 or set(cells[1].strip()) <= {"-"} or cells[1].strip() == "limit or check":
            continue
        tokens += re.findall(r"`([^`]+)`", cells[3])
    return sorted(set(tokens))


def is_path(token: str) -> bool:
    return token.endswith((".py", "/"))


def enforced_in_names() -> list[str]:
    return [n for n in enforced_in_cells() if not is_path(n) and IDENTIFIER.match(n) and n not in EXTERNAL]


SOURCES = {path: path.read_text(encoding="utf-8") for path in SRC.rglob("*.py")}


def defines(source: str, name: str) -> bool:
    return re.search(rf"^\s*(async\s+def|def|class)\s+{re.escape(name)}\b|^\s*(self\.)?{re.escape(name)}\s*[:=]",
                     source, re.M) is not None


def test_the_table_names_something() -> None:
    assert len(enforced_in_names()) > 40
    assert len([token for token in enforced_in_cells() if is_path(token)]) > 20


@pytest.mark.parametrize("path", [token for token in enforced_in_cells() if is_path(token)])
def test_each_path_in_the_limits_table_exists(path: str) -> None:
    assert (SRC / path).exists(), f"src/armwarden/{path} does not exist"


@pytest.mark.parametrize("name", enforced_in_names())
def test_each_name_in_the_limits_table_exists_in_the_code(name: str) -> None:
    owner, _, member = name.partition(".")
    if not member:
        assert any(defines(source, owner) for source in SOURCES.values()), f"{name} is defined nowhere in src/armwarden"
        return
    homes = [source for source in SOURCES.values() if re.search(rf"^class\s+{re.escape(owner)}\b", source, re.M)]
    assert homes, f"class {owner} is defined nowhere in src/armwarden"
    assert any(defines(source, member) for source in homes), f"{owner} has no {member}"
