"""The packages keep their layers (pyproject.toml's import-linter contract: tool layer → Guard →
safety checks → backends → core) and no module imports itself round a loop, so a newcomer can read
the code from the bottom up and a change low down cannot reach back into the layers above."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

from tests.helpers import REPO, SRC

LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")
#: loops still to be cut, each named with why it is there (empty is the goal)
KNOWN_LOOPS: dict[frozenset[str], str] = {}


def lint_imports(repo: Path, src: Path) -> subprocess.CompletedProcess[str]:
    """Run import-linter on the package under `src` with `repo`'s contract (a fresh cache each time)."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=repo, env=env, capture_output=True, text=True, timeout=300)


def import_loops() -> list[frozenset[str]]:
    """Every set of ArmWarden modules that import each other round a loop (type-checking imports too)."""
    graph = grimp.build_graph("armwarden", cache_dir=None)
    edges = {m: graph.find_modules_directly_imported_by(m) for m in graph.modules}
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    loops: list[frozenset[str]] = []

    def visit(module: str) -> None:  # Tarjan's strongly connected components
        order[module] = low[module] = len(order)
        stack.append(module)
        for target in edges[module]:
            if target not in order:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in stack:
                low[module] = min(low[module], order[target])
        if low[module] == order[module]:
            component = {stack.pop()}
            while module not in component:
                component.add(stack.pop())
            if len(component) > 1:
                loops.append(frozenset(component))

    for module in sorted(edges):
        if module not in order:
            visit(module)
    return loops


@pytest.fixture(scope="module")
def lint_imports_available() -> None:
    if not LINT_IMPORTS.exists():
        pytest.fail(f"{LINT_IMPORTS} is missing: install the dev extra (pip install -e '.[dev]')")


@pytest.mark.usefixtures("lint_imports_available")
def test_the_packages_keep_their_layers() -> None:
    result = lint_imports(REPO, SRC)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 kept, 0 broken" in result.stdout


@pytest.mark.usefixtures("lint_imports_available")
def test_an_import_that_runs_back_up_a_layer_breaks_the_contract(tmp_path: Path) -> None:
    shutil.copytree(SRC / "armwarden", tmp_path / "src" / "armwarden", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    trajectory = tmp_path / "src" / "armwarden" / "core" / "trajectory.py"
    trajectory.write_text(trajectory.read_text(encoding="utf-8") + "\nimport armwarden.guard  # noqa: E402\n", encoding="utf-8")
    result = lint_imports(tmp_path, tmp_path / "src")
    assert result.returncode == 1, result.stdout + result.stderr
    assert "BROKEN" in result.stdout and "armwarden.core.trajectory -> armwarden.guard" in result.stdout


def test_no_module_imports_itself_round_a_loop() -> None:
    unexpected = [sorted(loop) for loop in import_loops() if loop not in KNOWN_LOOPS]
    assert unexpected == []


def test_every_known_loop_is_still_there_so_a_cut_one_leaves_the_list() -> None:
    assert set(KNOWN_LOOPS) <= set(import_loops())
