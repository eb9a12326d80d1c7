"""Files the first hour leaves in a checkout that must never be committed are ignored by git: the
bearer token file the docs create (`armwarden tokens add tokens.json ...`) and the lock file that
`tokens add/revoke` keep beside it, whatever its name."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from armwarden.transport.tokens import TokenStore

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(),
                                reason="needs git and a git checkout")


def ignored(path: Path) -> bool:
    """Whether git ignores `path`, relative to the checkout (it need not exist there)."""
    result = subprocess.run(["git", "-C", str(REPO), "check-ignore", "--quiet", "--no-index", str(path)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode in (0, 1), result.stderr  # 128: git itself failed
    return result.returncode == 0


@pytest.mark.parametrize("name", ["tokens.json", "tokens.yaml", "tokens.yml"])
def test_every_file_tokens_add_writes_is_ignored_anywhere_in_the_checkout(tmp_path: Path, name: str) -> None:
    TokenStore.add(tmp_path / name, "operator", "alice")
    written = sorted(path.name for path in tmp_path.iterdir())
    assert name in written and len(written) >= 2, written  # the token file and its lock file
    for folder in (Path("."), Path("deploy")):
        for file_name in written:
            assert ignored(folder / file_name), folder / file_name


def test_the_token_store_source_is_not_ignored() -> None:
    assert not ignored(Path("src/armwarden/transport/tokens.py"))
