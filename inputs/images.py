"""Image files and decoded images as the pipeline takes them: uint8 grayscale (H, W)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from deepslam.inputs.source import SourceError
from deepslam.logs.images import MAX_PIXELS, encoded_size, too_large

RAW_ENCODINGS = {"mono8": (1, np.uint8), "mono16": (1, np.uint16), "rgb8": (3, np.uint8), "bgr8": (3, np.uint8),
                 "rgba8": (4, np.uint8), "bgra8": (4, np.uint8)}  # fmt: skip


def to_gray(image: np.ndarray, encoding: str) -> np.ndarray:
    """uint8 (H, W) of a decoded image in one of ``RAW_ENCODINGS`` (mono16 is scaled by 1/256)."""
    if encoding == "mono16":
        return (image >> 8).astype(np.uint8)
    if image.ndim == 2:
        return image
    code = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY,
            "bgra8": cv2.COLOR_BGRA2GRAY}[encoding]  # fmt: skip
    return cv2.cvtColor(image, code)


def read_image(path: Path) -> np.ndarray:
    """An image file as uint8 (H, W) or (H, W, 3) BGR (16 bits scaled by 1/256); ``SourceError`` if unreadable."""
    try:
        with open(path, "rb") as f:
            size = encoded_size(f.read(65536))
    except OSError as error:
        raise SourceError(f"{path}: cannot read the image ({error.strerror})") from None
    if too_large(size):
        raise SourceError(f"{path}: a {size[0]}x{size[1]} image is over the {MAX_PIXELS} pixels an input may hold")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SourceError(f"{path}: cannot read the image")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    return image[..., :3] if image.ndim == 3 else image


def image_sizes(files: list[Path]) -> tuple[int, int]:
    """The one (H, W) of all ``files``; SourceError if one is missing, unreadable or of another size."""
    size = None
    for path in files:
        if not path.exists():
            raise SourceError(f"{path}: no such image")
        shape = read_image(path).shape[:2]
        if size is not None and shape != size:
            raise SourceError(f"{path}: images change size ({size[0]}x{size[1]} then {shape[0]}x{shape[1]})")
        size = shape
    return size
