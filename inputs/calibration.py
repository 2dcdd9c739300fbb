"""A camera as an input describes it, and the rectifier that undistorts and resizes its images to the
pipeline's size (plumb_bob / radtan or equidistant, with OpenCV)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from deepslam.inputs import parsing
from deepslam.inputs.source import SourceError

FOCAL_RANGE = (1e-3, 1e3)  # plausible focal lengths, in multiples of the image's larger side
MAX_DISTORTION = 1000.0  # the largest distortion coefficient (fisheye k1-k4 and radtan k1, k2 stay below 10)
DISTORTION_MODELS = {"plumb_bob": "plumb_bob", "radtan": "plumb_bob", "radial-tangential": "plumb_bob",
                     "rational_polynomial": "plumb_bob", "equidistant": "equidistant", "fisheye": "equidistant",
                     "none": "none", "": "none"}  # fmt: skip


@dataclass(frozen=True)
class Calibration:
    """A camera as the input describes it: K (3, 3), distortion coefficients, their model ("plumb_bob",
    "equidistant" or "none") and the native image size (H, W)."""

    K: np.ndarray
    distortion: tuple[float, ...]
    model: str
    size: tuple[int, int]

    @staticmethod
    def from_yaml(path: str | Path, size: tuple[int, int] | None = None) -> Calibration:
        """The calibration file ``path`` (YAML: fx, fy, cx, cy, optional distortion (a list), model, width
        and height) for images of ``size`` (H, W); a declared size must be the images'."""
        path = Path(path)
        data = parsing.yaml_mapping(path)
        parsing.unknown_keys(path, data, CALIBRATION_KEYS)
        fx, fy, cx, cy = (parsing.yaml_number(data, key, path) for key in ("fx", "fy", "cx", "cy"))
        declared = _declared_size(data, path)
        if declared is not None and size is not None and declared != size:
            raise SourceError(
                f"{path}: declares {declared[0]}x{declared[1]} images, the input's are {size[0]}x{size[1]}"
            )
        native = declared or size
        if native is None:
            raise SourceError(f"{path}: the calibration needs width and height here")
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], np.float64)
        model = data.get("model", "plumb_bob")
        if not isinstance(model, str):
            raise SourceError(f"{path}: model must be a name such as plumb_bob, got {model!r}")
        return Calibration.checked(K, parsing.yaml_numbers(data, "distortion", path), model, native, path)

    @staticmethod
    def checked(K, distortion, model: str, size: tuple[int, int], where) -> Calibration:
        """A calibration, or SourceError naming ``where`` if it is not usable: focal lengths between
        ``FOCAL_RANGE`` times the image's larger side, the principal point within an image's size of the
        image, distortion coefficients finite and at most ``MAX_DISTORTION`` in size."""
        K, distortion = np.asarray(K, np.float64).reshape(3, 3), tuple(float(d) for d in distortion)
        if model.lower() not in DISTORTION_MODELS:
            raise SourceError(f"{where}: unsupported distortion model {model!r} (plumb_bob, radtan or equidistant)")
        model = DISTORTION_MODELS[model.lower()] if any(distortion) else "none"
        if not np.all(np.isfinite(K)) or not all(map(math.isfinite, distortion)):
            raise SourceError(f"{where}: the calibration is not finite")
        side = max(size)
        low, high = FOCAL_RANGE[0] * side, FOCAL_RANGE[1] * side
        if not (low <= K[0, 0] <= high and low <= K[1, 1] <= high):
            raise SourceError(
                f"{where}: focal lengths {K[0, 0]:g}, {K[1, 1]:g} px are not plausible for {size[0]}x{size[1]} "
                f"images (between {low:g} and {high:g})"
            )
        h, w = size
        if not (-w <= K[0, 2] <= 2 * w and -h <= K[1, 2] <= 2 * h):
            raise SourceError(
                f"{where}: the principal point ({K[0, 2]:g}, {K[1, 2]:g}) lies far outside {h}x{w} images"
            )
        if any(abs(d) > MAX_DISTORTION for d in distortion):
            raise SourceError(f"{where}: distortion coefficients over {MAX_DISTORTION:g} in size: {list(distortion)}")
        if model == "equidistant" and len(distortion) != 4:
            raise SourceError(f"{where}: the equidistant model needs 4 coefficients, got {len(distortion)}")
        return Calibration(K, distortion, model, size)

    def to_metadata(self) -> dict:
        return {"K": self.K.tolist(), "distortion": list(self.distortion), "model": self.model, "size": list(self.size)}


def _declared_size(data: dict, where: Path) -> tuple[int, int] | None:
    """(H, W) a calibration file declares (width and height, positive whole numbers), or None."""
    if "width" not in data and "height" not in data:
        return None
    values = [data.get(key) for key in ("height", "width")]
    if any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in values):
        raise SourceError(f"{where}: width and height must both be positive whole numbers, got {values[::-1]}")
    return values[0], values[1]


CALIBRATION_KEYS = ("fx", "fy", "cx", "cy", "model", "distortion", "width", "height")


class Rectifier:
    """Undistorts and resizes images of ``calibration`` to ``size`` (H, W); ``K`` is the camera matrix of
    the result (a pinhole, no distortion). An image that needs neither passes through unchanged."""

    def __init__(self, calibration: Calibration, size: tuple[int, int]):
        (h0, w0), (h, w) = calibration.size, size
        scale = np.diag([w / w0, h / h0, 1.0])
        shift = np.array([[1, 0, 0.5 * (w / w0 - 1)], [0, 1, 0.5 * (h / h0 - 1)], [0, 0, 1]])  # pixel centres
        self.K = shift @ scale @ calibration.K  # x' + 0.5 = s (x + 0.5): pixel centres stay centres
        self.size, self.maps = size, None
        if calibration.model == "equidistant":
            self.maps = cv2.fisheye.initUndistortRectifyMap(
                calibration.K, np.array(calibration.distortion), np.eye(3), self.K, (w, h), cv2.CV_32FC1
            )
        elif calibration.model == "plumb_bob":
            self.maps = cv2.initUndistortRectifyMap(
                calibration.K, np.array(calibration.distortion), np.eye(3), self.K, (w, h), cv2.CV_32FC1
            )

    def __call__(self, image: np.ndarray) -> np.ndarray:
        if self.maps is not None:
            return cv2.remap(image, *self.maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        if image.shape != self.size:
            return cv2.resize(image, self.size[::-1], interpolation=cv2.INTER_AREA)
        return image
