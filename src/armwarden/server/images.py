"""PNG helpers for image tool results (plan previews, camera snapshots).

Pillow is optional (`armwarden[image]`). `pillow_available()` says whether it is installed;
`downscale_png` raises `ImageSupportMissing` when it is not.

Input images come from outside the server (cameras, backends), so decoding is guarded: only
PNG is accepted, and the pixel count is checked from the header *before* any pixel data is
decompressed, so a small file claiming a huge image (a decompression bomb) is refused cheaply.
"""

from __future__ import annotations

import io
import os
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
#: freed Pillow memory blocks kept for reuse (`keep_freed_image_blocks`), and their largest size
KEPT_IMAGE_BLOCKS = 8
IMAGE_BLOCK_BYTES = 1 << 20


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


def keep_freed_image_blocks() -> bool:
    """Let Pillow reuse the memory of freed images instead of returning it to the system.

    A preview allocates about ten images (the picture, its masks, the palette patches); by
    default Pillow frees each one's memory, and the next allocation of that size faults its
    pages in afresh (≈ 1 ms of a 4 ms preview). Pillow then keeps up to `KEPT_IMAGE_BLOCKS`
    freed blocks, and images are allocated in blocks of at most `IMAGE_BLOCK_BYTES` (a preview
    fits in one), so at most 8 MiB stays reserved whatever size of image was freed. Process-wide
    (Pillow's allocator), so the daemon calls it once, when it builds its previewer; a user's own
    `PILLOW_BLOCKS_MAX` / `PILLOW_BLOCK_SIZE` are left as set. Returns whether it changed anything.
    """
    if os.environ.get("PILLOW_BLOCKS_MAX") or os.environ.get("PILLOW_BLOCK_SIZE"):
        return False
    try:
        from PIL import Image
    except ImportError:
        return False
    Image.core.set_block_size(IMAGE_BLOCK_BYTES)
    Image.core.set_blocks_max(KEPT_IMAGE_BLOCKS)
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

    The pixel rows are compressed in bands of `band_rows`, each band as its own deflate segment
    (a fresh compressor ended with a full flush: its bytes depend on that band alone, and
    segments concatenate into one valid zlib stream). The reference's segments and their Adler-32
    checksums are computed once; a picture then costs one comparison with the reference (as
    64-bit words), the scanlines and compression of the bands it changed, and a checksum combined
    from the bands' (`adler32_combine`). Same pixels, same chunks as `encode_png`, only the IDAT
    bytes differ.
    """

    def __init__(self, reference: Any, band_rows: int = 32) -> None:
        if reference.mode != "RGB":
            raise ValueError(f"BandedPngEncoder takes an RGB reference, got mode {reference.mode}")
        if band_rows < 1:
            raise ValueError(f"band_rows must be at least 1, got {band_rows}")
        self.size = reference.size
        self._band_rows = band_rows
        width, height = self.size
        self._row_bytes = 3 * width
        self._starts = range(0, height, band_rows)
        self._reference = _pixel_words(reference)
        bands = [self._band(self._reference, start) for start in self._starts]
        self._segments = [_deflate_segment(band) for band in bands]
        self._checksums = [zlib.adler32(band.data) for band in bands]

    def encode(self, image: Any) -> bytes:
        if image.mode != "RGB" or image.size != self.size:
            raise ValueError(f"expected an RGB picture of {self.size}, got {image.mode} {image.size}")
        words = _pixel_words(image)
        changed_rows = np.any(words != self._reference, axis=1)
        pieces = [b"\x78\x01"]  # zlib header: deflate, 32 KiB window, fastest
        checksum = 1  # Adler-32 of nothing
        for index, start in enumerate(self._starts):
            stop = start + self._band_rows
            if changed_rows[start:stop].any():
                band = self._band(words, start)
                segment, band_checksum = _deflate_segment(band), zlib.adler32(band.data)
            else:
                segment, band_checksum = self._segments[index], self._checksums[index]
            pieces.append(segment)
            checksum = adler32_combine(checksum, band_checksum, (min(stop, self.size[1]) - start) * (1 + self._row_bytes))
        pieces.append(b"\x03\x00")  # an empty final block (fixed Huffman codes)
        pieces.append(struct.pack(">I", checksum))
        return _rgb_png(self.size, b"".join(pieces))

    def _band(self, words: np.ndarray, start: int) -> np.ndarray:
        """PNG scanlines of the band of rows from `start`, from a picture's `_pixel_words`."""
        return _scanlines(words[start:start + self._band_rows].view(np.uint8)[:, :self._row_bytes])


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


def _pixel_words(image: Any) -> np.ndarray:
    """The picture's RGB rows as 64-bit words (height, ⌈3·width / 8⌉), zero-padded at the end of
    each row where 3·width is not a multiple of 8: comparing two pictures compares an eighth as
    many elements as bytes. Rows of whole words (the preview's widths) are viewed, not copied."""
    width, height = image.size
    row_bytes = 3 * width
    pixels = np.frombuffer(image.tobytes(), dtype=np.uint8).reshape(height, row_bytes)
    if row_bytes % 8 == 0:
        return pixels.view(np.uint64)
    padded = np.zeros((height, 8 * -(-row_bytes // 8)), dtype=np.uint8)
    padded[:, :row_bytes] = pixels
    return padded.view(np.uint64)


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
           "keep_freed_image_blocks", "pillow_available"]
