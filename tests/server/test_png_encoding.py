"""The preview's PNG writers give back exactly the pixels they were handed."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from armwarden.preview.images import (
    BandedPngEncoder,
    adler32_combine,
    encode_png,
    rgbx_image,
    rgbx_words,
)

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


def test_a_width_whose_rows_are_not_whole_words_keeps_every_pixel() -> None:
    reference = picture(width=201, height=50)
    changed = picture(width=201, height=50, seed=2)
    assert np.array_equal(pixels(BandedPngEncoder(reference, band_rows=8).encode(changed)), np.asarray(changed))


def idat(png: bytes) -> bytes:
    """The IDAT chunk's data (the writers put all pixels in one)."""
    offset = 8
    while offset < len(png):
        length, kind = struct.unpack(">I4s", png[offset:offset + 8])
        if kind == b"IDAT":
            return png[offset + 8:offset + 8 + length]
        offset += 12 + length
    raise AssertionError("no IDAT chunk")


def test_the_banded_stream_passes_zlibs_own_checksum_check() -> None:
    """zlib verifies the stream's Adler-32 (a decoder that stops at the last row may not)."""
    reference = picture(height=77)
    changed = reference.copy()
    ImageDraw.Draw(changed).line([(0, 20), (199, 60)], fill=(0, 80, 230), width=3)
    raw = zlib.decompress(idat(BandedPngEncoder(reference, band_rows=16).encode(changed)))
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(77, 1 + 3 * 200)
    assert np.all(rows[:, 0] == 0)
    assert np.array_equal(rows[:, 1:].reshape(77, 200, 3), np.asarray(changed))


@given(st.binary(max_size=3000), st.binary(max_size=3000))
def test_combined_checksums_equal_the_checksum_of_the_joined_bytes(first: bytes, second: bytes) -> None:
    assert adler32_combine(zlib.adler32(first), zlib.adler32(second), len(second)) == zlib.adler32(first + second)


def test_combined_checksums_hold_for_parts_longer_than_the_modulus() -> None:
    first, second = bytes(range(256)) * 300, b"\xff" * 200_003
    assert adler32_combine(zlib.adler32(first), zlib.adler32(second), len(second)) == zlib.adler32(first + second)


def test_a_picture_of_another_size_is_refused() -> None:
    with pytest.raises(ValueError, match="expected an RGB picture"):
        BandedPngEncoder(picture()).encode(picture(width=100))


def test_pillow_draws_into_the_words_of_an_rgbx_image() -> None:
    words = np.zeros((6, 10), dtype=np.uint32)
    image = rgbx_image(words)
    ImageDraw.Draw(image).line([(0, 1), (9, 1)], fill=(1, 2, 3), width=1)
    image.paste((7, 8, 9), (2, 3, 5, 5))

    channels = words.view(np.uint8).reshape(6, 10, 4)
    assert np.all(channels[1, :, :3] == (1, 2, 3))
    assert np.all(channels[3:5, 2:5, :3] == (7, 8, 9))
    assert np.all(channels[0] == 0) and np.all(channels[5] == 0)


def test_words_round_trip_through_an_rgbx_image() -> None:
    image = picture(width=37, height=11)
    words = rgbx_words(image)
    assert words.shape == (11, 37)
    assert rgbx_image(words).tobytes("raw", "RGB") == image.tobytes()


@pytest.mark.parametrize("words", [
    np.zeros((4, 4), dtype=np.uint8),  # not one word per pixel
    np.zeros((4, 8), dtype=np.uint32)[:, ::2],  # not contiguous
    np.zeros(16, dtype=np.uint32),  # not rows of pixels
])
def test_an_rgbx_image_is_not_laid_over_memory_of_another_shape(words: np.ndarray) -> None:
    with pytest.raises(ValueError, match="writable C-contiguous"):
        rgbx_image(words)


def test_an_rgbx_image_is_not_laid_over_read_only_memory() -> None:
    words = np.zeros((4, 4), dtype=np.uint32)
    words.setflags(write=False)
    with pytest.raises(ValueError, match="writable"):
        rgbx_image(words)


@pytest.mark.parametrize("width", [200, 201])  # rows of whole 64-bit words, and not
def test_a_picture_given_as_words_keeps_every_pixel(width: int) -> None:
    reference, changed = picture(width=width, height=77), picture(width=width, height=77, seed=3)
    png = BandedPngEncoder(rgbx_words(reference), band_rows=16).encode(rgbx_words(changed))
    assert np.array_equal(pixels(png), np.asarray(changed))


def test_runs_of_changed_bands_and_unchanged_bands_between_them_keep_every_pixel() -> None:
    reference = picture(height=160)
    changed = reference.copy()
    draw = ImageDraw.Draw(changed)
    draw.line([(0, 3), (199, 70)], fill=(0, 80, 230), width=3)  # bands 0 to 4, one run
    draw.rectangle((10, 130, 50, 140), fill=(9, 9, 9))  # band 8 alone, after unchanged bands
    raw = zlib.decompress(idat(BandedPngEncoder(reference, band_rows=16).encode(changed)))
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(160, 1 + 3 * 200)
    assert np.array_equal(rows[:, 1:].reshape(160, 200, 3), np.asarray(changed))


def test_a_picture_given_as_a_strided_view_keeps_every_pixel() -> None:
    reference = rgbx_words(picture(width=40, height=64))
    wider = np.zeros((64, 80), dtype=np.uint32)
    wider[:, :40] = rgbx_words(picture(width=40, height=64, seed=4))
    png = BandedPngEncoder(reference, band_rows=16).encode(wider[:, :40])  # a crop of a wider canvas
    assert np.array_equal(pixels(png), np.asarray(picture(width=40, height=64, seed=4)))


def test_the_encoder_keeps_its_own_reference_whatever_the_caller_does_with_its_buffer() -> None:
    buffer = rgbx_words(picture(width=40, height=64))
    view = buffer.view()
    view.setflags(write=False)  # read-only here, but the caller still writes the buffer
    encoder = BandedPngEncoder(view, band_rows=16)
    buffer[:] = rgbx_words(Image.new("RGB", (40, 64), (0, 0, 0)))

    assert np.array_equal(pixels(encoder.encode(buffer.copy())), np.zeros((64, 40, 3), dtype=np.uint8))
    assert not encoder.reference.flags.writeable
