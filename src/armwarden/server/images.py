"""PNG helpers for image tool results (plan previews, camera snapshots).

Pillow is optional (`armwarden[image]`). `pillow_available()` says whether it is installed;
`downscale_png` raises `ImageSupportMissing` when it is not.

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
    """Pillow is not installed."""

    def __init__(self) -> None:
        super().__init__("image support needs Pillow: install armwarden[image] (pip install 'armwarden[image]')")


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
    width, height = image.size
    rows = _png_rows(image)
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, no interlace
    return b"".join((PNG_SIGNATURE, _chunk(b"IHDR", header), _chunk(b"IDAT", zlib.compress(rows.tobytes(), PNG_ZLIB_LEVEL)),
                     _chunk(b"IEND", b"")))


class BandedPngEncoder:
    """`encode_png` for pictures that differ from one `reference` picture in a few rows only.

    The pixel rows are compressed in bands of `band_rows`, each band as its own deflate segment
    (a fresh compressor ended with a full flush: its bytes depend on that band alone, and
    segments concatenate into one valid zlib stream). The reference's segments are compressed
    once; a picture then costs a comparison with the reference and the compression of the bands
    it changed. Same pixels, same chunks as `encode_png`, only the IDAT bytes differ.
    """

    def __init__(self, reference: Any, band_rows: int = 32) -> None:
        if reference.mode != "RGB":
            raise ValueError(f"BandedPngEncoder takes an RGB reference, got mode {reference.mode}")
        if band_rows < 1:
            raise ValueError(f"band_rows must be at least 1, got {band_rows}")
        self.size = reference.size
        self._band_rows = band_rows
        self._reference = _png_rows(reference)
        self._segments = [_deflate_segment(band) for band in self._bands(self._reference)]

    def encode(self, image: Any) -> bytes:
        if image.mode != "RGB" or image.size != self.size:
            raise ValueError(f"expected an RGB picture of {self.size}, got {image.mode} {image.size}")
        rows = _png_rows(image)
        pieces = [b"\x78\x01"]  # zlib header: deflate, 32 KiB window, fastest
        for band, reference, segment in zip(self._bands(rows), self._bands(self._reference), self._segments, strict=True):
            pieces.append(segment if np.array_equal(band, reference) else _deflate_segment(band))
        pieces.append(b"\x03\x00")  # an empty final block (fixed Huffman codes)
        pieces.append(struct.pack(">I", zlib.adler32(rows.data) & 0xFFFFFFFF))
        width, height = self.size
        header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
        return b"".join((PNG_SIGNATURE, _chunk(b"IHDR", header), _chunk(b"IDAT", b"".join(pieces)), _chunk(b"IEND", b"")))

    def _bands(self, rows: np.ndarray) -> list[np.ndarray]:
        return [rows[start:start + self._band_rows] for start in range(0, rows.shape[0], self._band_rows)]


def _png_rows(image: Any) -> np.ndarray:
    """The picture's PNG scanlines: filter type 0 (None) and the RGB bytes of each row."""
    width, height = image.size
    rows = np.empty((height, 1 + 3 * width), dtype=np.uint8)
    rows[:, 0] = 0
    rows[:, 1:] = np.frombuffer(image.tobytes(), dtype=np.uint8).reshape(height, 3 * width)
    return rows


def _deflate_segment(rows: np.ndarray) -> bytes:
    compressor = zlib.compressobj(PNG_ZLIB_LEVEL, zlib.DEFLATED, -15)  # raw deflate: the header is shared
    return compressor.compress(np.ascontiguousarray(rows).data) + compressor.flush(zlib.Z_FULL_FLUSH)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


__all__ = ["MAX_PIXELS", "BandedPngEncoder", "ImageSupportMissing", "downscale_png", "encode_png", "pillow_available"]
