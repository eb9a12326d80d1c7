"""scripts/mutation.py stays honest: every mutant's edit still lands on today's code.

No mutant is run here (that takes minutes: `python scripts/mutation.py`). What is checked is what
a refactor silently breaks: each anchor occurs exactly once in its file, the edited file still
compiles, and each mutant's test selection names tests that exist.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from types import ModuleType

import pytest

from tests.helpers import REPO, SRC

ISSUE_32_CHECKS = ("door-estop-latch-gate", "door-last-stop-check", "base-stop-landed", "runner-in-contact",
                   "runner-require-wrench", "approval-reset-always", "checks-grasp-force")


def _load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("armwarden_mutation_script", REPO / "scripts" / "mutation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the script loads
    spec.loader.exec_module(module)
    return module


mutation = _load_script()
MUTANTS = mutation.MUTANTS
TEST_SOURCES = "\n".join(path.read_text(encoding="utf-8") for path in (REPO / "tests").rglob("*.py"))


def test_mutant_names_are_unique_and_the_run_covers_the_seven_checks_of_issue_32() -> None:
    names = [mutant.name for mutant in MUTANTS]
    assert len(names) == len(set(names))
    assert set(ISSUE_32_CHECKS) <= set(names)


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.name for m in MUTANTS])
def test_each_anchor_matches_exactly_once_and_the_edit_compiles(mutant) -> None:
    target = SRC / "armwarden" / mutant.path
    source = target.read_text(encoding="utf-8")
    assert source.count(mutant.anchor) == 1, f"{mutant.name}: anchor no longer matches exactly once in {target}"
    compile(mutation.mutated_source(mutant, source), str(target), "exec")


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.name for m in MUTANTS])
def test_each_selected_test_exists(mutant) -> None:
    assert mutant.tests
    for node in mutant.tests:
        path, _, rest = node.partition("::")
        assert (REPO / path).is_file(), f"{mutant.name}: no test file {path}"
        if rest:
            name = re.sub(r"\[.*\]$", "", rest.split("::")[-1])
            assert re.search(rf"def {re.escape(name)}\(", TEST_SOURCES), f"{mutant.name}: no test named {name}"


def test_an_anchor_that_no_longer_matches_is_an_error_not_a_skip() -> None:
    vanished = mutation.Mutant("vanished", "guard/door.py", "if self.no_such_check:", "if False:", ("tests",), "gone")
    with pytest.raises(ValueError, match="found 0 times"):
        mutation.mutated_source(vanished, "if self.other_check:\n    pass\n")
    with pytest.raises(ValueError, match="found 2 times"):
        mutation.mutated_source(vanished, "if self.no_such_check:\n    a()\nif self.no_such_check:\n    b()\n")


def test_a_mutant_is_a_one_line_edit() -> None:
    two_lines = mutation.Mutant("two-lines", "guard/door.py", "if a:\n    raise X", "pass", ("tests",), "no")
    with pytest.raises(ValueError, match="one-line edit"):
        mutation.mutated_source(two_lines, "if a:\n    raise X\n")
