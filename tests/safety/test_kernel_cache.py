"""The envelope's kernels are cached by numba under names that carry a digest of every source
compiled into them, because numba checks only the file that defines an entry point: a helper
edited in another module must not leave stale machine code in use."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from types import ModuleType

import numba.core.registry

import armwarden.safety.kernel
from armwarden.robot import batch_fk
from armwarden.safety.kernel import driver, jit


def kernel_modules() -> list[ModuleType]:
    names = [info.name for info in pkgutil.iter_modules(armwarden.safety.kernel.__path__, "armwarden.safety.kernel.")]
    return [importlib.import_module(name) for name in names] + [batch_fk]


def test_every_module_defining_compiled_code_is_in_the_cache_digest() -> None:
    defining = {
        Path(value.py_func.__code__.co_filename).resolve()
        for module in kernel_modules()
        for value in vars(module).values()
        if isinstance(value, numba.core.registry.CPUDispatcher)
    }
    assert Path(batch_fk.__file__).resolve() in defining
    assert Path(driver.__file__).resolve() in defining
    assert defining <= {path.resolve() for path in jit.COMPILED_SOURCES}


def test_each_entry_point_is_cached_under_the_digest_of_the_sources() -> None:
    for entry in (driver.check_path, driver.check_samples, driver.check_configuration):
        assert entry.py_func.__qualname__ == f"{entry.py_func.__name__}_{jit.SOURCES_DIGEST}"
    assert jit.sources_digest(list(jit.COMPILED_SOURCES)) == jit.SOURCES_DIGEST


def test_an_edit_to_a_helper_module_changes_the_digest(tmp_path: Path) -> None:
    copies = []
    for source in jit.COMPILED_SOURCES:
        copy = tmp_path / source.name
        copy.write_bytes(source.read_bytes())
        copies.append(copy)
    before = jit.sources_digest(copies)
    predicates = tmp_path / "predicates.py"
    predicates.write_text(predicates.read_text().replace("return math.sqrt(best)", "return best"))
    assert jit.sources_digest(copies) != before
