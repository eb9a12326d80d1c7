"""scripts/demo.py — the scripted stdio session — runs end to end and every step behaves."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_demo_session_passes_every_step(tmp_path: Path) -> None:
    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))}
    env.pop("ARMWARDEN_AUDIT_KEY", None)
    completed = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "demo.py"), "--out", str(tmp_path)],
        check=False, capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path,
    )
    transcript = completed.stdout + completed.stderr
    assert completed.returncode == 0, transcript
    assert "All steps behaved as expected" in completed.stdout
    assert (tmp_path / "preview.png").read_bytes().startswith(b"\x89PNG")
    assert (tmp_path / "audit.jsonl").stat().st_size > 0
