"""The wheel carries everything the runtime loads from its own package, and runs from it alone.

`pip install .` (and a future PyPI release) gets exactly what the wheel holds: a data file the
package-data globs miss is there in the source tree, so every test run from the checkout passes,
and only an installed daemon fails to start. The wheel is built offline from a copy of the tree
(`--no-build-isolation --no-index`: setuptools and wheel come from the dev extra) and compared
with the package directory file by file.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import armwarden
from armwarden.policy.loading import bundled_policy
from armwarden.robots import builtin_robots, load_profile
from tests.helpers import REPO

#: what the build never copies into a wheel, and should not
_NOT_SHIPPED = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "build")


def _package_files(package: Path) -> set[str]:
    """Every file of the package directory, as its name inside the wheel (`armwarden/...`)."""
    return {
        path.relative_to(package.parent).as_posix()
        for path in package.rglob("*")
        if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc"
    }


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the checkout's build inputs: the build writes into its source tree, and the wheel
    is compared with the very files it was built from."""
    source = tmp_path_factory.mktemp("source")
    shutil.copy2(REPO / "pyproject.toml", source)
    shutil.copy2(REPO / "README.md", source)  # pyproject's `readme`
    shutil.copytree(REPO / "src", source / "src", ignore=_NOT_SHIPPED)
    return source


@pytest.fixture(scope="module")
def wheel(source: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel pip builds offline from `source` (setuptools and wheel come from the dev extra)."""
    out = tmp_path_factory.mktemp("dist")
    result = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "--no-index",
         "--disable-pip-version-check", "--quiet", "-w", str(out)],
        capture_output=True, text=True, timeout=240, check=False,
    )
    assert result.returncode == 0, f"pip wheel failed:\n{result.stdout}\n{result.stderr}"
    (built,) = out.glob("armwarden-*.whl")
    return built


@pytest.fixture(scope="module")
def unpacked(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    target = tmp_path_factory.mktemp("unpacked")
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(target)
    return target


def _wheel_names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as archive:
        return set(archive.namelist())


def test_wheel_holds_every_file_of_the_package(source: Path, wheel: Path) -> None:
    missing = sorted(_package_files(source / "src" / "armwarden") - _wheel_names(wheel))
    assert missing == [], f"not in the wheel (pyproject.toml [tool.setuptools.package-data]): {missing}"


def test_wheel_holds_the_bundled_files_the_runtime_opens(wheel: Path) -> None:
    """Named from the code that opens them, so a file deleted from the tree is caught too."""
    needed = {f"armwarden/robots/{robot}/{name}" for robot in builtin_robots() for name in
              ("profile.yaml", load_profile(robot).description, load_profile(robot).collision_geometry) if name}
    needed |= {f"armwarden/robots/fr3/{bundled_policy(name).name}" for name in ("fr3", "readonly")}
    needed |= {"armwarden/py.typed", "armwarden/console/templates/base.html", "armwarden/console/static/console.js",
               "armwarden/console/static/console.css"}
    assert sorted(needed - _wheel_names(wheel)) == []


def test_wheel_declares_the_console_script(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        (entry_points,) = [name for name in archive.namelist() if name.endswith(".dist-info/entry_points.txt")]
        text = archive.read(entry_points).decode()
    assert "armwarden = armwarden.cli:main" in text


@pytest.mark.parametrize("policy", ["fr3", "readonly"])
def test_check_policy_runs_from_the_unpacked_wheel_alone(unpacked: Path, tmp_path: Path, policy: str) -> None:
    """The bundled policy, its URDF and fitted geometry, loaded from the wheel's files, not the checkout's."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env["PYTHONPATH"] = str(unpacked)
    # numba would compile the envelope's kernels afresh for this new path (about 25 s); which files
    # the wheel carries is what is tested here, and the kernels run as plain Python just the same
    env["NUMBA_DISABLE_JIT"] = "1"
    probe = ("import sys, armwarden; print('imported from', armwarden.__file__); "
             "from armwarden.cli import main; sys.exit(main(sys.argv[1:]))")
    policy_file = unpacked / "armwarden" / bundled_policy(policy).relative_to(Path(armwarden.__file__).parent)
    result = subprocess.run([sys.executable, "-c", probe, "check-policy", str(policy_file)], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=120, check=False)
    assert f"imported from {unpacked / 'armwarden' / '__init__.py'}" in result.stdout
    assert result.returncode == 0, result.stdout + result.stderr
    assert "home configuration passes the envelope" in result.stdout
