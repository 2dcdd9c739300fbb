"""The size of an encoded image read from its header, so that an image too large to hold is refused
before it is decoded (a 20000x20000 PNG of a few kilobytes decodes to gigabytes)."""

from __future__ import annotations

import struct

MAX_PIXELS = 8192 * 8192  # the largest image (pixels) an input may hold: an 8K video frame is 33 million
JPEG_FRAME_MARKERS = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def encoded_size(data: bytes) -> tuple[int, int] | None:
    """(H, W) of a PNG, JPEG or BMP image from its header, or None for another format or a broken header."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        width, height = struct.unpack(">II", data[16:24])
        return height, width
    if data[:2] == b"BM" and len(data) >= 26:
        width, height = struct.unpack("<ii", data[18:26])
        return abs(height), abs(width)
    if data[:2] == b"\xff\xd8":
        return _jpeg_size(data)
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(H, W) from a JPEG's frame header (the first SOF segment), or None."""
    position = 2
    while position + 9 <= len(data):
        if data[position] != 0xFF:
            return None
        marker = data[position + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:  # no length: skip the marker
            position += 1 if marker == 0xFF else 2
            continue
        length = struct.unpack(">H", data[position + 2 : position + 4])[0]
        if marker in JPEG_FRAME_MARKERS:
            height, width = struct.unpack(">HH", data[position + 5 : position + 9])
            return height, width
        position += 2 + length
    return None


def too_large(size: tuple[int, int] | None) -> bool:
    """Whether an image of ``size`` (H, W), if known, holds more than ``MAX_PIXELS``."""
    return size is not None and size[0] * size[1] > MAX_PIXELS
