"""The console's camera view over real HTTP: each camera the backend declares, its latest
picture for any signed-in session, read through the Guard as `camera_snapshot` reads it (the
policy's allowlist, the backend's errors as refusals, the policy's rate limits), shared between
viewers, and never in the audit log."""

from __future__ import annotations

import io
from pathlib import Path

import httpx2
import numpy as np
import pytest
from PIL import Image

from armwarden.core.errors import BackendError
from tests.console.served import ServedConsole, served_console, sign_in
from tests.helpers import REPO, FakeClock, records_of
from tests.server.harness import policy_with
from tests.server.http_daemon import http_daemon

EXAMPLE_SCENE = REPO / "examples" / "mujoco_scene.yaml"

pytestmark = pytest.mark.anyio

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def picture_size(png: bytes) -> tuple[int, int]:
    return Image.open(io.BytesIO(png)).size


async def test_a_camera_picture_needs_sign_in(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        picture = await http.get("/console/cameras/scene.png")
        page = await http.get("/console/cameras")

    assert picture.status_code == 401 and not picture.content.startswith(PNG_MAGIC)
    assert page.status_code == 303 and page.headers["location"].endswith("/console/login")


async def test_an_observer_sees_each_camera_the_backend_declares(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        page = await http.get("/console/cameras")
        pictures = {name: await http.get(f"/console/cameras/{name}.png") for name in ("wrist", "scene")}

    assert page.status_code == 200
    assert 'data-camera="wrist"' in page.text and 'data-camera="scene"' in page.text
    assert all(p.status_code == 200 and p.headers["content-type"] == "image/png" for p in pictures.values())
    assert all(picture_size(p.content) == (320, 240) for p in pictures.values())
    assert all(p.headers["cache-control"] == "no-store" for p in pictures.values())


async def test_no_pixels_and_no_record_per_picture_reach_the_audit_log(tmp_path: Path) -> None:
    clock = FakeClock(0.0)
    async with served_console(tmp_path, session_clock=clock) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        served.harness.audit.flush()
        before = len(records_of(served.harness.audit_path))
        shown = []
        for _ in range(5):
            shown.append((await http.get("/console/cameras/scene.png")).content)
            clock.advance(60.0)  # a new picture each time
        served.harness.audit.flush()
        log = served.harness.audit_path.read_bytes()
        after = len(records_of(served.harness.audit_path))

    assert len(set(shown)) == 5 and all(png.startswith(PNG_MAGIC) for png in shown)
    assert after == before  # reads of the console are not audited, like its live sections
    assert b"iVBORw0KGgo" not in log and PNG_MAGIC not in log  # no picture, encoded or raw


async def test_an_unknown_camera_is_404_with_a_message_naming_the_cameras(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        answer = await http.get("/console/cameras/kitchen.png")

    assert answer.status_code == 404
    error = answer.json()["error"]
    assert "no camera 'kitchen'" in error and "wrist, scene" in error


async def test_a_failing_camera_shows_its_error_and_the_page_still_renders(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        async def broken(camera: str) -> None:
            raise BackendError(f"{camera}: lens cap on")

        cameras = served.harness.fake.cell.cameras
        assert cameras is not None
        cameras.snapshot = broken  # type: ignore[method-assign]
        await sign_in(http, served.operator_token)
        answer = await http.get("/console/cameras/wrist.png")
        page = await http.get("/console/cameras")
        other = await http.get("/console/cameras/scene.png")

    assert answer.status_code == 503
    assert "BACKEND_ERROR" in answer.json()["error"] and "wrist: lens cap on" in answer.json()["error"]
    assert page.status_code == 200 and "wrist: lens cap on" in page.text
    assert other.status_code == 503  # each camera reports for itself


def count_camera_reads(served: ServedConsole) -> list[str]:
    """The cameras the fake backend is asked for from now on, in order."""
    reads: list[str] = []
    cameras = served.harness.fake.cell.cameras
    assert cameras is not None
    original = cameras.snapshot

    async def counted(camera: str):
        reads.append(camera)
        return await original(camera)

    cameras.snapshot = counted  # type: ignore[method-assign]
    return reads


async def test_a_camera_the_policy_does_not_allow_is_refused_without_a_backend_read(tmp_path: Path) -> None:
    policy = policy_with(**{"perception.cameras": ["scene"]})
    async with served_console(tmp_path, policy) as served, served.browser_client() as http:
        reads = count_camera_reads(served)
        await sign_in(http, served.operator_token)
        page = await http.get("/console/cameras")
        wrist = await http.get("/console/cameras/wrist.png")
        scene = await http.get("/console/cameras/scene.png")

    assert wrist.status_code == 403 and "not allowlisted" in wrist.json()["error"]
    assert scene.status_code == 200
    assert reads == ["scene"]
    assert 'data-camera="wrist"' in page.text and "not allowlisted" in page.text


async def test_with_the_perception_group_disabled_no_camera_is_shown_or_read(tmp_path: Path) -> None:
    """The policy still lists cameras under perception.cameras but does not enable the `perception`
    tool group, so no client is served `camera_snapshot`: the console shows no picture either."""
    policy = policy_with(**{"tools.enabled": ["introspect", "motion", "gripper", "control", "safety"]})
    async with served_console(tmp_path, policy) as served, served.browser_client() as http:
        reads = count_camera_reads(served)
        await sign_in(http, served.observer_token)
        page = await http.get("/console/cameras")
        pictures = {name: await http.get(f"/console/cameras/{name}.png") for name in ("wrist", "scene")}

    assert reads == []
    for picture in pictures.values():
        assert picture.status_code == 403 and not picture.content.startswith(PNG_MAGIC)
        assert "NOT_ALLOWED" in picture.json()["error"] and "perception" in picture.json()["error"]
    assert page.status_code == 200 and "perception" in page.text and "tools.enabled" in page.text


async def test_a_backend_without_cameras_shows_no_cameras(tmp_path: Path) -> None:
    """The minimal example backend declares no camera."""
    async with served_console(tmp_path, backend="minimal") as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        page = await http.get("/console/cameras")

    assert page.status_code == 200
    assert 'id="no-cameras"' in page.text and "No cameras" in page.text


async def test_viewers_share_one_backend_read_per_refresh_interval(tmp_path: Path) -> None:
    clock = FakeClock(0.0)
    async with served_console(tmp_path, session_clock=clock) as served, \
            served.browser_client() as alice, served.browser_client() as bob:
        await sign_in(alice, served.operator_token)
        await sign_in(bob, served.observer_token)
        first = (await alice.get("/console/cameras/scene.png")).content
        same = (await bob.get("/console/cameras/scene.png")).content
        clock.advance(60.0)
        newer = (await bob.get("/console/cameras/scene.png")).content

    assert same == first  # one read served both viewers
    assert newer != first


async def test_the_policys_rate_limits_bound_the_consoles_reads(tmp_path: Path) -> None:
    """One picture a minute across all cameras: the second camera waits, the first keeps its
    latest picture; the agent's own budget for camera_snapshot is not spent by viewers."""
    clock = FakeClock(0.0)
    policy = policy_with(**{"rate_limits.global_per_minute": 1, "rate_limits.per_tool": {"camera_snapshot": 1}})
    async with served_console(tmp_path, policy, session_clock=clock) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        scene = await http.get("/console/cameras/scene.png")
        clock.advance(1.0)
        wrist = await http.get("/console/cameras/wrist.png")
        clock.advance(1.0)
        scene_again = await http.get("/console/cameras/scene.png")
        async with served.mcp_client() as client:
            agent = await client.call_tool("camera_snapshot", {"camera": "scene"})

    assert scene.status_code == 200
    assert wrist.status_code == 429 and "rate limit" in wrist.json()["error"]
    assert scene_again.status_code == 200 and scene_again.content == scene.content  # the latest, kept
    assert not agent.is_error


async def test_the_camera_view_refreshes_as_often_as_the_rate_limits_allow(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        page = await http.get("/console/cameras")

    # the bundled policy: camera_snapshot 30/min per camera, so every 2 s
    assert 'data-camera-refresh="2000"' in page.text


async def test_the_mujoco_daemons_rendered_cameras_are_shown(tmp_path: Path) -> None:
    """`armwarden serve --backend mujoco` with the README's scene, as a process of its own (its
    physics and renderer do not share this test process's interpreter)."""
    pytest.importorskip("mujoco")
    with http_daemon(tmp_path, speedup=1.0, backend="mujoco", config=EXAMPLE_SCENE) as daemon:
        async with httpx2.AsyncClient(base_url=daemon.base, timeout=30) as http:
            await sign_in(http, daemon.observer_token)
            page = await http.get("/console/cameras")
            pictures = {name: await http.get(f"/console/cameras/{name}.png") for name in ("scene", "wrist")}

    assert 'data-camera="scene"' in page.text and 'data-camera="wrist"' in page.text
    for picture in pictures.values():
        assert picture.status_code == 200, picture.text
        image = Image.open(io.BytesIO(picture.content)).convert("L")
        assert image.size == (640, 480)
        assert np.asarray(image, dtype=float).std() > 10.0  # a rendered scene, not a blank
