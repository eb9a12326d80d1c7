#!/usr/bin/env python3
"""Build the ROS 2 interface packages that are not on PyPI into a Python environment.

control_msgs, controller_manager_msgs and tf2_msgs (the subsets under ros/interfaces/, Jazzy's exact field
layouts) are generated with the rosidl/ament wheels of the ``ros`` extra and installed into the
environment's prefix, which the wheels already use as their install space. Run it with the
environment's own interpreter, or name the prefix:

    .venv/bin/python scripts/build_ros_interfaces.py            # into sys.prefix
    python3 scripts/build_ros_interfaces.py --prefix .venv -j1  # into another venv

Idempotent: a stamp holding a hash of the sources is written next to each installed package; a
package whose stamp matches is skipped. A package that a sourced ROS install already provides
(found on AMENT_PREFIX_PATH outside the target prefix) is left alone unless ``--force``.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
INTERFACES = ROOT / "ros" / "interfaces"
PACKAGES = ("control_msgs", "controller_manager_msgs", "tf2_msgs")
STAMP_NAME = "armwarden_interfaces.sha256"
BUILD_RECIPE_VERSION = "1"  # bump when the way packages are built changes (forces a rebuild)

_INCLUDE_LINE = re.compile(r'(INTERFACE_INCLUDE_DIRECTORIES\s+")([^"]*)(")')


@dataclass(frozen=True)
class Target:
    """The environment the packages are built for and installed into."""

    prefix: Path
    python: Path


def log(message: str) -> None:
    print(f"[build_ros_interfaces] {message}", file=sys.stderr, flush=True)


def source_hash(package_dir: Path, python_tag: str) -> str:
    """Hash of every source file of a package (path and bytes), the recipe and the interpreter."""
    digest = hashlib.sha256(f"{BUILD_RECIPE_VERSION}\n{python_tag}\n".encode())
    for path in sorted(p for p in package_dir.rglob("*") if p.is_file()):
        digest.update(path.relative_to(package_dir).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def query_target(prefix: Path) -> tuple[Path, str, str]:
    """The target's interpreter, its tag, and its Python and NumPy include directories."""
    python = prefix / "bin" / "python"
    if not python.exists():
        raise SystemExit(f"no Python interpreter at {python}: is {prefix} a virtual environment?")
    code = (
        "import sys, sysconfig, numpy;"
        "print(f'{sys.implementation.cache_tag}');"
        "print(sysconfig.get_paths()['include']);"
        "print(numpy.get_include())"
    )
    out = subprocess.run([str(python), "-c", code], check=True, capture_output=True, text=True).stdout.split("\n")
    return python, out[0], ";".join([out[1], out[2]])


def fix_python_exports(prefix: Path, include_dirs: str) -> int:
    """Point the prebuilt ``*__rosidl_generator_pyExport.cmake`` files at this environment.

    The message wheels were built elsewhere and export that machine's Python and NumPy include
    paths; linking our generated Python extension against them fails at configure time.
    Returns the number of files rewritten.
    """
    changed = 0
    for path in sorted(prefix.glob("share/*/cmake/*__rosidl_generator_pyExport.cmake")):
        text = path.read_text()
        new = _INCLUDE_LINE.sub(lambda m: m.group(1) + include_dirs + m.group(3), text)
        if new != text:
            path.write_text(new)
            changed += 1
    return changed


def provided_elsewhere(package: str, prefix: Path) -> Path | None:
    """The first AMENT_PREFIX_PATH entry other than the target that already has the package."""
    for entry in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if entry and Path(entry).resolve() != prefix.resolve() and (Path(entry) / "share" / package / "package.xml").exists():
            return Path(entry)
    return None


def build_env(prefix: Path) -> dict[str, str]:
    env = dict(os.environ)

    def prepend(name: str, value: str) -> None:
        env[name] = value + (os.pathsep + env[name] if env.get(name) else "")

    prepend("AMENT_PREFIX_PATH", str(prefix))
    prepend("CMAKE_PREFIX_PATH", str(prefix))
    prepend("PATH", str(prefix / "bin"))
    prepend("LD_LIBRARY_PATH", str(prefix / "lib"))
    return env


def build_package(package: str, target: Target, jobs: int, keep_build: Path | None) -> None:
    source = INTERFACES / package
    env = build_env(target.prefix)
    with tempfile.TemporaryDirectory(prefix=f"armwarden-{package}-") as tmp:
        build = keep_build / package if keep_build else Path(tmp)
        if keep_build and build.exists():
            shutil.rmtree(build)
        configure = [
            "cmake",
            "-S",
            str(source),
            "-B",
            str(build),
            f"-DCMAKE_INSTALL_PREFIX={target.prefix}",
            f"-DPython3_EXECUTABLE={target.python}",
            "-DBUILD_TESTING=OFF",
            "-DCMAKE_BUILD_TYPE=Release",
        ]
        for step in (configure, ["cmake", "--build", str(build), "-j", str(jobs)], ["cmake", "--install", str(build)]):
            result = subprocess.run(step, env=env, capture_output=True, text=True)
            if result.returncode != 0:
                sys.stderr.write(result.stdout[-6000:] + result.stderr[-6000:])
                raise SystemExit(f"{package}: `{' '.join(step[:2])}` failed (exit {result.returncode})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--prefix", type=Path, default=Path(sys.prefix), help="environment to build into (default: this interpreter's)")
    parser.add_argument("-j", "--jobs", type=int, default=os.cpu_count() or 1, help="parallel compile jobs")
    parser.add_argument("--force", action="store_true", help="rebuild even when the stamp matches or a sourced ROS has the package")
    parser.add_argument("--keep-build", type=Path, default=None, help="keep the CMake build trees under this directory")
    parser.add_argument("packages", nargs="*", metavar="PACKAGE", help=f"packages to build (default: all of {', '.join(PACKAGES)})")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.packages) - set(PACKAGES))
    if unknown:
        parser.error(f"unknown package(s) {', '.join(unknown)}; known: {', '.join(PACKAGES)}")

    prefix = args.prefix.absolute()
    if shutil.which("cmake") is None:
        raise SystemExit("cmake not found on PATH (and a C/C++ compiler is needed too)")
    python, tag, include_dirs = query_target(prefix)
    target = Target(prefix=prefix, python=python)
    for package in args.packages or PACKAGES:
        stamp = prefix / "share" / package / STAMP_NAME
        wanted = source_hash(INTERFACES / package, tag)
        if not args.force:
            other = provided_elsewhere(package, prefix)
            if other is not None:
                log(f"{package}: provided by the sourced ROS install at {other}; not built")
                continue
            if stamp.exists() and stamp.read_text().strip() == wanted:
                log(f"{package}: up to date in {prefix}")
                continue
        rewritten = fix_python_exports(prefix, include_dirs)
        if rewritten:
            log(f"rewrote the Python/NumPy include paths in {rewritten} exported CMake files")
        started = time.monotonic()
        log(f"{package}: building into {prefix} (-j{args.jobs})")
        build_package(package, target, args.jobs, args.keep_build)
        stamp.write_text(wanted + "\n")
        log(f"{package}: installed in {time.monotonic() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
