"""PNG helpers for image tool results (plan previews, camera snapshots).

Pillow is a core dependency: an environment without it is a broken install (`armwarden serve`
says so at start-up, `armwarden.extras`). `pillow_available()` says whether it can be imported;
`downscale_png` raises `ImageSupportMissing` when it cannot.

Input images come from outside the server (cameras, backends), so decoding is guarded: only
PNG is accepted, and the pixel count is checked from the header *before* any pixel data is
decompressed, so a small file claiming a huge image (a decompression bomb) is refused cheaply.
"""

from __future__ import annotations

import io
import struct
import warnings
import zlib
from typing import Any

import numpy as np

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: zlib level of `encode_png`: 1 is the fastest that still shrinks a drawing ~30x
PNG_ZLIB_LEVEL = 1
#: largest image (width × height) `downscale_png` will decode
MAX_PIXELS = 40_000_000


class ImageSupportMissing(RuntimeError):
    """Pillow cannot be imported: the install is broken (it is a core dependency)."""

    def __init__(self) -> None:
        super().__init__("Pillow is missing from this environment: reinstall armwarden (Pillow is one of its "
                         "dependencies; pip install pillow restores it)")


def pillow_available() -> bool:
    try:
        import PIL.Image  # noqa: F401
    except ImportError:
        return False
    return True


def downscale_png(png: bytes, max_width: int) -> tuple[bytes, int, int]:
    """Re-encode `png` no wider than `max_width`, keeping its aspect ratio; returns (png, width, height).

    Never enlarges. The result is always a freshly encoded PNG (ancillary chunks such as text
    metadata are dropped). Raises ValueError for input that is not a decodable PNG or has more
    than `MAX_PIXELS` pixels, and for a `max_width` below 1; `ImageSupportMissing` without Pillow.
    """
    if isinstance(max_width, bool) or not isinstance(max_width, int) or max_width < 1:
        raise ValueError(f"max_width must be a positive integer, got {max_width!r}")
    if not isinstance(png, (bytes, bytearray, memoryview)):
        raise ValueError(f"expected PNG bytes, got {type(png).__name__}")
    data = bytes(png)
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError("not a PNG image (bad signature)")
    try:
        from PIL import Image
    except ImportError as exc:
        raise ImageSupportMissing() from exc

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data), formats=["PNG"])  # lazy: reads the header only
            width, height = image.size
            if width < 1 or height < 1 or width * height > MAX_PIXELS:
                raise ValueError(f"PNG of {width}x{height} px exceeds the {MAX_PIXELS} pixel limit")
            image.load()
    except ValueError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ValueError(f"PNG exceeds the pixel limit (possible decompression bomb): {exc}") from exc
    except Exception as exc:  # Pillow raises OSError / SyntaxError / struct.error etc. on broken files
        raise ValueError(f"cannot decode PNG: {exc}") from exc

    if image.mode not in ("RGB", "RGBA", "L", "LA"):
        has_alpha = "A" in image.mode or "transparency" in image.info
        image = image.convert("RGBA" if has_alpha else "RGB")
    if width > max_width:
        new_w = max_width
        new_h = max(1, round(height * max_width / width))
        image = image.resize((new_w, new_h), Image.Resampling.LANCZOS, reducing_gap=3.0)
        width, height = new_w, new_h
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue(), width, height


def encode_png(image: Any) -> bytes:
    """PNG bytes of an 8-bit RGB Pillow image, every row with filter type 0 (None).

    Why not ``image.save(format="PNG")``: Pillow tries every PNG row filter on every row, which
    costs more than the compression itself (about 3 ms for a 640x320 drawing, against about 1 ms
    here); a drawing of flat colours compresses about as well unfiltered. No metadata chunks, so
    the same pixels give the same bytes.
    """
    if image.mode != "RGB":
        raise ValueError(f"encode_png takes an RGB image, got mode {image.mode}")
    return _rgb_png(image.size, zlib.compress(_png_rows(image).tobytes(), PNG_ZLIB_LEVEL))


class BandedPngEncoder:
    """`encode_png` for pictures that differ from one `reference` picture in a few rows only.

    Pictures are given as `rgbx_words` arrays (one 32-bit word per pixel, as Pillow keeps an RGB
    image in memory; the preview draws straight into one), or as RGB Pillow images, converted.
    The pixel rows are cut in bands of `band_rows`, and the stream is made of deflate segments
    (each from a fresh compressor ended with a full flush: its bytes depend on its own rows
    alone, and segments concatenate into one valid zlib stream). The reference's bands are
    compressed once, a segment each, with their Adler-32 checksums; a picture then costs one
    comparison with the reference (two pixels per 64-bit word), the scanlines, checksum and
    compression (still a segment per band) of each run of consecutive bands it changed, and a
    checksum combined from the parts' (`adler32_combine`). Same pixels, same chunks as
    `encode_png`, only the IDAT bytes differ.
    """

    def __init__(self, reference: Any, band_rows: int = 32) -> None:
        if band_rows < 1:
            raise ValueError(f"band_rows must be at least 1, got {band_rows}")
        words = _as_words(reference, None)
        height, width = words.shape
        self.size = (width, height)
        self._band_rows = band_rows
        self._row_bytes = 3 * width
        self._starts = range(0, height, band_rows)
        self._reference = words.copy()  # its own: the cached segments must match it whatever the caller does
        self._reference.setflags(write=False)
        self._compared = _comparable(self._reference)
        bands = [self._scanlines(self._reference, start, start + band_rows) for start in self._starts]
        self._segments = [_deflate_segment(band) for band in bands]
        self._checksums = [zlib.adler32(band.data) for band in bands]

    @property
    def reference(self) -> np.ndarray:
        """The reference picture's words (read-only)."""
        return self._reference

    def encode(self, picture: Any) -> bytes:
        words = _as_words(picture, self.size)
        changed_rows = np.any(_comparable(words) != self._compared, axis=1)
        changed = np.logical_or.reduceat(changed_rows, np.asarray(self._starts)).tolist()
        pieces = [b"\x78\x01"]  # zlib header: deflate, 32 KiB window, fastest
        checksum = 1  # Adler-32 of nothing
        index = 0
        while index < len(changed):
            end = index + 1
            if changed[index]:  # a run of changed bands: packed and checksummed at once
                while end < len(changed) and changed[end]:
                    end += 1
                rows = self._scanlines(words, self._starts[index], self._starts[end - 1] + self._band_rows)
                # but deflated a segment per band: a compressor fed more than its 64 KiB buffer
                # slides its window, which costs more than starting a fresh one
                pieces += [_deflate_segment(rows[k:k + self._band_rows]) for k in range(0, len(rows), self._band_rows)]
                checksum = adler32_combine(checksum, zlib.adler32(rows.data), rows.size)
            else:
                pieces.append(self._segments[index])
                checksum = adler32_combine(checksum, self._checksums[index], self._band_length(index))
            index = end
        pieces.append(b"\x03\x00")  # an empty final block (fixed Huffman codes)
        pieces.append(struct.pack(">I", checksum))
        return _rgb_png(self.size, b"".join(pieces))

    def _band_length(self, index: int) -> int:
        """Bytes of scanlines in band `index` (the last may be short)."""
        start = self._starts[index]
        return (min(start + self._band_rows, self.size[1]) - start) * (1 + self._row_bytes)

    def _scanlines(self, words: np.ndarray, start: int, stop: int) -> np.ndarray:
        """PNG scanlines of the rows from `start` to `stop`: Pillow packs the words' RGB bytes (one
        C pass over those rows, no copy of the rest of the picture)."""
        rows = np.ascontiguousarray(words[start:stop])
        packed = _image_over(rows, "RGBX").tobytes("raw", "RGB")
        return _scanlines(np.frombuffer(packed, dtype=np.uint8).reshape(rows.shape[0], self._row_bytes))


def rgbx_words(image: Any) -> np.ndarray:
    """An RGB Pillow image's pixels as a (height, width) array of 32-bit words, the bytes R, G,
    B, 255 of each pixel in memory order (Pillow's own layout of an RGB image)."""
    if image.mode != "RGB":
        raise ValueError(f"expected an RGB image, got mode {image.mode}")
    width, height = image.size
    return np.frombuffer(image.tobytes("raw", "RGBX"), dtype=np.uint32).reshape(height, width).copy()


def rgbx_image(words: np.ndarray) -> Any:
    """A writable RGBX Pillow image over `words` ((height, width) uint32, C-contiguous), sharing
    its memory: what Pillow draws on it lands in the array, without a copy either way."""
    return _drawable(_image_over(words, "RGBX"), words)


def mask_image(mask: np.ndarray) -> Any:
    """A writable "L" Pillow image over `mask` ((height, width) uint8, C-contiguous), sharing its
    memory, as `rgbx_image`."""
    return _drawable(_image_over(mask, "L"), mask)


#: the array each Pillow mode laid over an array takes: one element per pixel
_MODE_DTYPES = {"RGBX": np.uint32, "L": np.uint8}


def _image_over(array: np.ndarray, mode: str) -> Any:
    """A Pillow image of `mode` over a (height, width) array's memory (read-only, as Pillow marks it)."""
    from PIL import Image

    if array.dtype != _MODE_DTYPES[mode] or array.ndim != 2 or not array.flags.c_contiguous:
        raise ValueError(f"expected a writable C-contiguous (height, width) {np.dtype(_MODE_DTYPES[mode])} array")
    height, width = array.shape
    return Image.frombuffer(mode, (width, height), array, "raw", mode, 0, 1)


def _drawable(image: Any, array: np.ndarray) -> Any:
    """`image`, over `array`'s memory, made writable in place. Pillow marks images over foreign
    memory read-only and copies them on the first write; the array is ours and writable, so the
    mark is cleared. `tests/server/test_png_encoding.py` checks that drawing lands in the array."""
    if not array.flags.writeable:
        raise ValueError("expected a writable C-contiguous array, got a read-only one")
    image.readonly = 0
    return image


def _as_words(picture: Any, size: tuple[int, int] | None) -> np.ndarray:
    """A picture's words, C-contiguous (a strided view, a crop of a wider canvas, is copied)."""
    words = picture if isinstance(picture, np.ndarray) else rgbx_words(picture)
    if words.dtype != np.uint32 or words.ndim != 2:
        raise ValueError(f"expected (height, width) uint32 pixel words, got {words.dtype} {words.shape}")
    if size is not None and (words.shape[1], words.shape[0]) != size:
        raise ValueError(f"expected an RGB picture of {size}, got {(words.shape[1], words.shape[0])}")
    return np.ascontiguousarray(words)


def _comparable(words: np.ndarray) -> np.ndarray:
    """C-contiguous words as 64-bit (two pixels each) where the width allows it: an eighth as many
    elements to compare as bytes."""
    return words.view(np.uint64) if words.shape[1] % 2 == 0 else words


#: the modulus of Adler-32 (the largest prime below 2**16)
_ADLER_MOD = 65521


def adler32_combine(first: int, second: int, second_length: int) -> int:
    """The Adler-32 of two byte strings joined, from their own checksums and the second's length.

    Adler-32 is two sums mod 65521: A = 1 + the bytes, B = the sum of A after each byte. Joined,
    A adds the second part's bytes, A₂ − 1; and each of the second part's B terms is its own A
    plus the first part's bytes, A₁ − 1, so B gains B₂ + length₂·(A₁ − 1). (zlib has this as
    `adler32_combine`; Python's `zlib` module does not expose it.)
    """
    a1, b1 = first & 0xFFFF, first >> 16
    a2, b2 = second & 0xFFFF, second >> 16
    a = (a1 + a2 - 1) % _ADLER_MOD
    b = (b1 + b2 + second_length * (a1 - 1)) % _ADLER_MOD
    return (b << 16) | a


def _scanlines(pixels: np.ndarray) -> np.ndarray:
    """PNG scanlines of RGB rows (rows, 3·width): filter type 0 (None) before each row."""
    rows = np.empty((pixels.shape[0], 1 + pixels.shape[1]), dtype=np.uint8)
    rows[:, 0] = 0
    rows[:, 1:] = pixels
    return rows


def _png_rows(image: Any) -> np.ndarray:
    """The picture's PNG scanlines: filter type 0 (None) and the RGB bytes of each row."""
    width, height = image.size
    return _scanlines(np.frombuffer(image.tobytes(), dtype=np.uint8).reshape(height, 3 * width))


def _deflate_segment(rows: np.ndarray) -> bytes:
    compressor = zlib.compressobj(PNG_ZLIB_LEVEL, zlib.DEFLATED, -15)  # raw deflate: the header is shared
    return compressor.compress(np.ascontiguousarray(rows).data) + compressor.flush(zlib.Z_FULL_FLUSH)


def _rgb_png(size: tuple[int, int], idat: bytes) -> bytes:
    """A PNG file of an 8-bit RGB picture of `size` (no interlace) from its zlib stream `idat`,
    without metadata chunks: the same pixels always give the same bytes."""
    header = struct.pack(">IIBBBBB", size[0], size[1], 8, 2, 0, 0, 0)
    return b"".join((PNG_SIGNATURE, _chunk(b"IHDR", header), _chunk(b"IDAT", idat), _chunk(b"IEND", b"")))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


__all__ = ["MAX_PIXELS", "BandedPngEncoder", "ImageSupportMissing", "adler32_combine", "downscale_png", "encode_png",
           "mask_image", "pillow_available", "rgbx_image", "rgbx_words"]
