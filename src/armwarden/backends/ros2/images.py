"""Camera messages to PNG: `sensor_msgs/Image` with 8-bit encodings, and `CompressedImage`.

Raw images are encoded here (zlib, no Pillow); a compressed PNG is passed through after its
header is checked; a JPEG needs Pillow to become a PNG. Anything else — other encodings, a data
length that does not match width × height × channels, absurd sizes — is refused, never guessed.
"""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np

from armwarden.core.errors import BackendError

#: channels of each accepted encoding, and the channel order to put it in RGB(A) order
ENCODINGS: dict[str, tuple[int, tuple[int, ...]]] = {
    "rgb8": (3, (0, 1, 2)),
    "bgr8": (3, (2, 1, 0)),
    "mono8": (1, (0,)),
    "8uc1": (1, (0,)),
    "rgba8": (4, (0, 1, 2, 3)),
    "bgra8": (4, (2, 1, 0, 3)),
}
#: larger images are refused [px]
MAX_SIDE_PX = 8192
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}  # channels -> PNG colour type (grey, RGB, RGBA)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def encode_png(pixels: np.ndarray) -> bytes:
    """PNG bytes of an (height, width[, channels]) uint8 array (1, 3 or 4 channels)."""
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    height, width, channels = pixels.shape
    header = struct.pack(">IIBBBBB", width, height, 8, _PNG_COLOUR_TYPE[channels], 0, 0, 0)
    rows = np.concatenate([np.zeros((height, 1), dtype=np.uint8), pixels.reshape(height, width * channels)], axis=1)
    return _PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)) + _chunk(b"IEND", b"")


def png_from_image(msg) -> tuple[int, int, bytes]:
    """(width, height, PNG) of a sensor_msgs/Image."""
    encoding = str(msg.encoding).lower()
    if encoding not in ENCODINGS:
        raise BackendError(f"image encoding {msg.encoding!r} is not supported (8-bit: {', '.join(ENCODINGS)})")
    channels, order = ENCODINGS[encoding]
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if not (0 < width <= MAX_SIDE_PX and 0 < height <= MAX_SIDE_PX):
        raise BackendError(f"image size {width}x{height} px is outside 1..{MAX_SIDE_PX}")
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if step < width * channels or len(data) < step * height:
        raise BackendError(f"image data does not fit {width}x{height} {encoding} (step {step}, {len(data)} bytes)")
    pixels = data[: step * height].reshape(height, step)[:, : width * channels].reshape(height, width, channels)
    return width, height, encode_png(np.ascontiguousarray(pixels[:, :, list(order)]))


def png_from_compressed(msg) -> tuple[int, int, bytes]:
    """(width, height, PNG) of a sensor_msgs/CompressedImage holding a PNG or a JPEG."""
    data = bytes(msg.data)
    if data.startswith(_PNG_SIGNATURE) and len(data) >= 24 and data[12:16] == b"IHDR":
        width, height = struct.unpack(">II", data[16:24])
        if not (0 < width <= MAX_SIDE_PX and 0 < height <= MAX_SIDE_PX):
            raise BackendError(f"image size {width}x{height} px is outside 1..{MAX_SIDE_PX}")
        return width, height, data
    if data.startswith(b"\xff\xd8"):
        try:
            from PIL import Image  # JPEG only (Pillow is a core dependency)
        except ImportError:
            raise BackendError("a JPEG camera image needs Pillow to become a PNG, and Pillow is missing from this "
                               "environment: reinstall armwarden") from None
        try:
            with Image.open(io.BytesIO(data)) as image:
                if not (0 < image.width <= MAX_SIDE_PX and 0 < image.height <= MAX_SIDE_PX):
                    raise BackendError(f"image size {image.width}x{image.height} px is outside 1..{MAX_SIDE_PX}")
                out = io.BytesIO()
                image.convert("RGB").save(out, format="PNG")
                return image.width, image.height, out.getvalue()
        except OSError as exc:
            raise BackendError(f"the JPEG camera image cannot be decoded: {exc}") from exc
    raise BackendError(f"compressed image format {msg.format!r} is neither PNG nor JPEG")


__all__ = ["ENCODINGS", "encode_png", "png_from_compressed", "png_from_image"]
