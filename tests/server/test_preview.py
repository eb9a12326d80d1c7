"""The plan preview picture and the PNG downscaler."""

from __future__ import annotations

import io
import struct
import sys
import zlib

import numpy as np
import pytest

from armwarden.core.trajectory import JointTrajectory
from armwarden.policy import bundled_policy, load_policy
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.preview import images
from armwarden.preview.images import ImageSupportMissing, downscale_png, pillow_available
from armwarden.preview.render import render_plan_preview
from tests.helpers import READY

Image = pytest.importorskip("PIL.Image")

@pytest.fixture(scope="module")
def runtime() -> RuntimeModel:
    return load_runtime_model(load_policy(bundled_policy("fr3")))


def _plan(runtime: RuntimeModel, goal: np.ndarray):
    trajectory = runtime.planner.plan_to_joints(READY, goal).trajectory
    return trajectory, runtime.envelope.check(trajectory)


@pytest.fixture(scope="module")
def accepted(runtime: RuntimeModel):
    goal = READY.copy()
    goal[0] = 0.6  # a small turn of the base joint, clear of everything
    return _plan(runtime, goal)


@pytest.fixture(scope="module")
def into_monitor(runtime: RuntimeModel):
    goal = READY.copy()
    goal[[0, 1, 3]] = 0.9, 0.3, -1.6  # reach out, front left, into the monitor zone
    return _plan(runtime, goal)


def _render(runtime: RuntimeModel, plan, **kwargs) -> bytes:
    trajectory, report = plan
    png = render_plan_preview(runtime.robot, runtime.envelope.limits, trajectory, report, **kwargs)
    assert png is not None
    return png


def _decode(png: bytes):
    image = Image.open(io.BytesIO(png))
    image.load()
    return image


def _strongly_red(png: bytes) -> int:
    rgb = np.asarray(_decode(png).convert("RGB")).astype(int)
    return int(np.sum((rgb[..., 0] > 200) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)))


def _png(width: int, height: int, colour=(10, 120, 200)) -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (width, height), colour).save(out, format="PNG")
    return out.getvalue()


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


# ---------------------------------------------------------------------------- preview
def test_preview_is_a_png_of_the_requested_size(runtime: RuntimeModel, accepted) -> None:
    png = _render(runtime, accepted, size=(520, 280))
    assert png.startswith(images.PNG_SIGNATURE)
    image = _decode(png)
    assert image.format == "PNG"
    assert image.size == (520, 280)


def test_default_preview_is_640_by_320(runtime: RuntimeModel, accepted) -> None:
    assert _decode(_render(runtime, accepted)).size == (640, 320)


def test_identical_inputs_give_identical_bytes(runtime: RuntimeModel, into_monitor) -> None:
    assert _render(runtime, into_monitor) == _render(runtime, into_monitor)


def test_plan_into_a_keep_out_zone_is_marked_with_red_crosses(runtime: RuntimeModel, into_monitor) -> None:
    _trajectory, report = into_monitor
    assert any(v.code.value == "KEEP_OUT" and v.time_s is not None for v in report.violations)
    assert _strongly_red(_render(runtime, into_monitor)) > 20


def test_accepted_plan_has_no_red_crosses_and_looks_different(runtime: RuntimeModel, accepted, into_monitor) -> None:
    assert not accepted[1].violations
    png = _render(runtime, accepted)
    assert _strongly_red(png) == 0
    assert png != _render(runtime, into_monitor)


def test_status_override_changes_the_picture(runtime: RuntimeModel, accepted) -> None:
    assert _render(runtime, accepted, status="needs_approval") != _render(runtime, accepted)


def test_malformed_trajectory_still_renders_the_zones(runtime: RuntimeModel, accepted) -> None:
    _, report = accepted
    broken = JointTrajectory(runtime.robot.joint_names, np.array([0.0, 1.0]), np.vstack([READY, np.full(7, np.nan)]))
    png = render_plan_preview(runtime.robot, runtime.envelope.limits, broken, report)
    assert png is not None and _decode(png).size == (640, 320)


def test_too_small_a_preview_is_refused(runtime: RuntimeModel, accepted) -> None:
    with pytest.raises(ValueError, match="at least"):
        _render(runtime, accepted, size=(40, 20))


def test_preview_is_none_without_pillow(runtime: RuntimeModel, accepted, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "PIL", None)  # makes `import PIL...` raise ImportError
    trajectory, report = accepted
    assert render_plan_preview(runtime.robot, runtime.envelope.limits, trajectory, report) is None


# ---------------------------------------------------------------------------- downscale_png
def test_downscale_keeps_the_aspect_ratio() -> None:
    png, width, height = downscale_png(_png(800, 600), 400)
    assert (width, height) == (400, 300)
    assert _decode(png).size == (400, 300)


def test_downscale_never_enlarges() -> None:
    png, width, height = downscale_png(_png(120, 90), 400)
    assert (width, height) == (120, 90)
    assert _decode(png).size == (120, 90)


def test_downscale_keeps_the_pixels_recognisable() -> None:
    png, _, _ = downscale_png(_png(300, 200, colour=(200, 30, 40)), 150)
    assert _decode(png).convert("RGB").getpixel((75, 50)) == (200, 30, 40)


def test_non_png_input_is_refused() -> None:
    jpeg = io.BytesIO()
    Image.new("RGB", (10, 10)).save(jpeg, format="JPEG")
    with pytest.raises(ValueError, match="not a PNG"):
        downscale_png(jpeg.getvalue(), 100)


def test_truncated_png_is_refused() -> None:
    with pytest.raises(ValueError, match="cannot decode"):
        downscale_png(_png(200, 200)[:60], 100)


def test_png_header_claiming_a_huge_image_is_refused_before_decoding() -> None:
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 2, 0, 0, 0)  # 10 gigapixels, 8-bit RGB
    bomb = images.PNG_SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b"\0" * 64)) + _chunk(b"IEND", b"")
    with pytest.raises(ValueError, match="pixel limit"):
        downscale_png(bomb, 100)


def test_image_above_the_pixel_limit_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(images, "MAX_PIXELS", 50 * 50)
    with pytest.raises(ValueError, match="pixel limit"):
        downscale_png(_png(60, 60), 30)


def test_non_positive_max_width_is_refused() -> None:
    with pytest.raises(ValueError, match="max_width"):
        downscale_png(_png(10, 10), 0)


def test_pillow_is_reported_available() -> None:
    assert pillow_available()


def test_without_pillow_downscale_raises_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    png = _png(10, 10)
    monkeypatch.setitem(sys.modules, "PIL", None)
    assert not pillow_available()
    # Pillow is a core dependency: its absence is a broken install, not a missing extra
    with pytest.raises(ImageSupportMissing, match=r"Pillow is missing from this environment: reinstall armwarden") as raised:
        downscale_png(png, 5)
    assert "[image]" not in str(raised.value)


def test_keep_out_marks_lie_inside_the_drawn_zone(runtime: RuntimeModel, into_monitor) -> None:
    """Picture correctness on the rendered geometry: each keep-out violation's cross is drawn,
    in both views, inside the pixel rectangle of the zone it violates (and the pixel there is red)."""
    from armwarden.preview.render import PlanPreviewer, _bounds, _plan_geometry

    trajectory, report = into_monitor
    previewer = PlanPreviewer(runtime.envelope.limits)
    rgb = np.asarray(_decode(previewer.render(runtime.robot, trajectory, report)).convert("RGB")).astype(int)
    geometry = _plan_geometry(runtime.robot, trajectory, report, previewer.limits)
    assert geometry is not None
    scene = previewer._scene(*_bounds(previewer.limits, geometry))
    timed = [v for v in report.violations if v.time_s is not None]
    keep_out = [k for k, v in enumerate(timed) if v.code.value == "KEEP_OUT"]
    monitor = next(zone for zone in previewer.limits.keep_out if zone.name == "monitor")

    assert keep_out
    for view in scene.views:
        left, top, right, bottom = view.rect(monitor.lo, monitor.hi)
        for k in keep_out:
            x, y = view.pts(geometry.marks[k:k + 1])[0]
            assert left <= x <= right and min(top, bottom) <= y <= max(top, bottom), (view.axis_v, (x, y))
            r, g, b = rgb[round(y), round(x)]
            assert r > 200 and g < 60 and b < 60


TITLE = [("   duration ", False), ("12.07", True), (" s   TCP path ", False), ("0.489", True), (" m", False),
         ("   violations: ", False), ("3", True), (" hard, ", False), ("10", True), (" soft", False)]


def _title_scene(runtime: RuntimeModel):
    from armwarden.preview.render import PlanPreviewer

    previewer = PlanPreviewer(runtime.envelope.limits)
    limits = runtime.envelope.limits
    return previewer._scene(np.asarray(limits.workspace.lo, dtype=float), np.asarray(limits.workspace.hi, dtype=float))


def _plain_picture(scene):
    """The scene's picture without a plan, as an RGB Pillow image of its own."""
    return scene.start().convert("RGB")


def test_a_title_drawn_from_stamps_is_the_title_pillow_draws(runtime: RuntimeModel) -> None:
    from PIL import ImageDraw

    scene = _title_scene(runtime)
    stamped, drawn = _plain_picture(scene), _plain_picture(scene)

    assert scene.line(stamped, 40.0, 2.0, TITLE, (40, 40, 40))
    ImageDraw.Draw(drawn).text((40.0, 2.0), "".join(text for text, _ in TITLE), fill=(40, 40, 40), font=scene.font)
    differing = np.any(np.asarray(stamped).astype(int) != np.asarray(drawn).astype(int), axis=-1)
    assert np.sum(differing) <= 2  # where two glyphs' anti-aliased edges overlap


def test_a_title_that_would_not_land_on_whole_pixels_is_left_to_pillow(runtime: RuntimeModel) -> None:
    scene = _title_scene(runtime)
    image = _plain_picture(scene)

    assert not scene.line(image, 40.5, 2.0, TITLE, (40, 40, 40))
    assert image.tobytes() == _plain_picture(scene).tobytes()


def test_a_title_pillow_must_place_itself_is_still_drawn(runtime: RuntimeModel, accepted, monkeypatch) -> None:
    """Where the title's glyphs would not land on whole pixels, the renderer stamps the title as
    one piece instead: the picture shows the same title."""
    from armwarden.preview.render import PlanPreviewer
    from armwarden.preview.scene import Scene

    trajectory, report = accepted
    stamped = np.asarray(_decode(PlanPreviewer(runtime.envelope.limits).render(runtime.robot, trajectory, report)))
    monkeypatch.setattr(Scene, "line", lambda *args, **kwargs: False)
    whole = np.asarray(_decode(PlanPreviewer(runtime.envelope.limits).render(runtime.robot, trajectory, report)))

    assert np.sum(np.any(stamped != whole, axis=-1)) <= 2  # where two glyphs' anti-aliased edges overlap
    title_rows = whole[:14, 60:]
    assert np.sum(np.any(title_rows != 255, axis=-1)) > 100  # the words after the status are there
