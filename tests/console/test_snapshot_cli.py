"""`armwarden snapshot CAMERA --out FILE --url URL --token-file FILE` against a real daemon
(`armwarden serve --transport http`, fake backend) over HTTP on 127.0.0.1: the picture written
and said, the call audited like any other (without its pixels), and a clear error with a non-zero
exit for an unknown camera, a refused token, an unreachable daemon."""

from __future__ import annotations

import io
import subprocess
from collections.abc import Iterator
from pathlib import Path

import anyio
import pytest
from PIL import Image

from tests.helpers import CLI, REPO, child_env, free_port, wait_for_record
from tests.server.http_daemon import Daemon, http_daemon


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("snapshot-daemon"), speedup=10) as running:
        yield running


def token_file(tmp_path: Path, token: str) -> Path:
    path = tmp_path / "token"
    path.write_text(token + "\n", encoding="utf-8")
    return path


def snapshot(tmp_path: Path, camera: str, url: str, token: str) -> tuple[subprocess.CompletedProcess[str], Path]:
    out = tmp_path / f"{camera}.png"
    done = subprocess.run([*CLI, "snapshot", camera, "--out", str(out), "--url", url,
                           "--token-file", str(token_file(tmp_path, token))],
                          cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=120)
    return done, out


def test_snapshot_writes_the_picture_and_says_what_it_wrote(daemon: Daemon, tmp_path: Path) -> None:
    done, out = snapshot(tmp_path, "scene", daemon.url, daemon.observer_token)

    assert done.returncode == 0, done.stderr
    assert str(out) in done.stdout and "320x240 px" in done.stdout and "'scene'" in done.stdout
    assert Image.open(io.BytesIO(out.read_bytes())).size == (320, 240)


def test_a_snapshot_is_audited_like_any_call_without_its_pixels(daemon: Daemon, tmp_path: Path) -> None:
    done, _ = snapshot(tmp_path, "wrist", daemon.url, daemon.observer_token)

    def is_the_call(record: dict) -> bool:
        return record.get("tool") == "camera_snapshot" and record.get("arguments") == {"camera": "wrist"} \
            and str(record.get("session", "")).startswith("armwarden-snapshot")

    records = anyio.run(wait_for_record, daemon.audit, is_the_call)

    assert done.returncode == 0, done.stderr
    call = next(r for r in records if is_the_call(r))
    assert call["principal"] == "bob" and call["outcome"] == "ok"
    assert b"iVBORw0KGgo" not in daemon.audit.read_bytes()  # no picture in the log


def test_an_unknown_camera_is_a_clear_error(daemon: Daemon, tmp_path: Path) -> None:
    done, out = snapshot(tmp_path, "kitchen", daemon.url, daemon.operator_token)

    assert done.returncode == 1
    assert "snapshot FAILED" in done.stderr and "'kitchen' is not allowlisted" in done.stderr
    assert "wrist" in done.stderr and "scene" in done.stderr  # what there is
    assert not out.exists()


def test_a_refused_token_is_a_clear_error(daemon: Daemon, tmp_path: Path) -> None:
    done, out = snapshot(tmp_path, "scene", daemon.url, "aw_not-a-real-token")

    assert done.returncode == 1
    assert "refused the token (401" in done.stderr
    assert not out.exists()


def test_an_unreachable_daemon_is_a_clear_error(tmp_path: Path) -> None:
    done, out = snapshot(tmp_path, "scene", f"http://127.0.0.1:{free_port()}/mcp", "aw_any")

    assert done.returncode == 1
    assert "cannot reach the daemon" in done.stderr
    assert not out.exists()


def test_an_unreadable_token_file_is_refused_as_invalid_input(tmp_path: Path) -> None:
    done = subprocess.run([*CLI, "snapshot", "scene", "--out", str(tmp_path / "x.png"), "--url",
                           "http://127.0.0.1:1/mcp", "--token-file", str(tmp_path / "missing")],
                          cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=120)

    assert done.returncode == 2
    assert "cannot read token file" in done.stderr
