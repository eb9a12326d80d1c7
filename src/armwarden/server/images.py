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
    rows = np.empty((height, 1 + 3 * width), dtype=np.uint8)
    rows[:, 0] = 0  # filter type None
    rows[:, 1:] = np.frombuffer(image.tobytes(), dtype=np.uint8).reshape(height, 3 * width)
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, no interlace
    return b"".join((PNG_SIGNATURE, _chunk(b"IHDR", header), _chunk(b"IDAT", zlib.compress(rows.tobytes(), PNG_ZLIB_LEVEL)),
                     _chunk(b"IEND", b"")))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


__all__ = ["MAX_PIXELS", "ImageSupportMissing", "downscale_png", "encode_png", "pillow_available"]
