"""The ROS run's `-p tests_ros.no_skips` turns every skip (and xfail) into a failure naming it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

SKIPPING = '''
import pytest

def test_runs():
    pass

def test_skips_itself():
    pytest.skip("no gripper declared")

@pytest.mark.xfail(reason="known bug")
def test_expected_to_fail():
    assert False
'''


def test_a_skip_and_an_xfail_fail_the_run_and_name_their_reasons(tmp_path: Path) -> None:
    (tmp_path / "test_skipping.py").write_text(SKIPPING)
    env = dict(os.environ, PYTHONPATH=str(ROOT))

    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "tests_ros.no_skips", "-p", "no:cacheprovider", "-q", "-o", "addopts=", str(tmp_path)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
    )

    assert run.returncode == 1, run.stdout
    assert "2 failed, 1 passed" in run.stdout
    assert "was skipped (Skipped: no gripper declared)" in run.stdout
    assert "was xfailed (known bug)" in run.stdout
