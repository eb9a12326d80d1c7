"""The preview's PNG writers give back exactly the pixels they were handed."""

from __future__ import annotations

import io

import numpy as np
import pytest

from armwarden.server.images import BandedPngEncoder, encode_png

Image = pytest.importorskip("PIL.Image")
ImageDraw = pytest.importorskip("PIL.ImageDraw")


def picture(width: int = 200, height: int = 90, seed: int = 0):
    rng = np.random.default_rng(seed)
    image = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    for _ in range(12):
        x0, y0 = rng.integers(0, width), rng.integers(0, height)
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        draw.rectangle((x0, y0, x0 + 20, y0 + 7), fill=colour)
    return image


def pixels(png: bytes) -> np.ndarray:
    decoded = Image.open(io.BytesIO(png))
    decoded.load()
    assert decoded.mode == "RGB"
    return np.asarray(decoded)


def test_encode_png_keeps_every_pixel() -> None:
    image = picture()
    assert np.array_equal(pixels(encode_png(image)), np.asarray(image))


def test_a_picture_equal_to_the_reference_keeps_every_pixel() -> None:
    reference = picture()
    assert np.array_equal(pixels(BandedPngEncoder(reference, band_rows=16).encode(reference.copy())), np.asarray(reference))


def test_a_picture_changed_in_some_bands_keeps_every_pixel() -> None:
    reference = picture()
    changed = reference.copy()
    ImageDraw.Draw(changed).line([(0, 40), (199, 47)], fill=(0, 80, 230), width=3)
    png = BandedPngEncoder(reference, band_rows=16).encode(changed)
    assert np.array_equal(pixels(png), np.asarray(changed))


def test_a_height_that_is_not_a_multiple_of_the_band_keeps_every_pixel() -> None:
    reference = picture(height=77)
    changed = picture(height=77, seed=1)
    assert np.array_equal(pixels(BandedPngEncoder(reference, band_rows=32).encode(changed)), np.asarray(changed))


def test_a_picture_of_another_size_is_refused() -> None:
    with pytest.raises(ValueError, match="expected an RGB picture"):
        BandedPngEncoder(picture()).encode(picture(width=100))
