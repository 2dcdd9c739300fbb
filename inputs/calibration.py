"""A camera as an input describes it, and the rectifier that undistorts and resizes its images to the
pipeline's size (plumb_bob / radtan or equidistant, with OpenCV)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from deepslam.inputs.source import SourceError

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
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except (OSError, yaml.YAMLError) as error:
            raise SourceError(f"{path}: cannot read the calibration ({error})") from None
        missing = [k for k in ("fx", "fy", "cx", "cy") if not isinstance(data, dict) or k not in data]
        if missing:
            raise SourceError(f"{path}: the calibration lacks {', '.join(missing)}")
        native = (int(data["height"]), int(data["width"])) if "height" in data and "width" in data else size
        if native is None:
            raise SourceError(f"{path}: the calibration needs width and height here")
        K = np.array([[data["fx"], 0, data["cx"]], [0, data["fy"], data["cy"]], [0, 0, 1]], np.float64)
        return Calibration.checked(K, data.get("distortion") or [], str(data.get("model", "plumb_bob")), native, path)

    @staticmethod
    def checked(K, distortion, model: str, size: tuple[int, int], where) -> Calibration:
        """A calibration, or SourceError naming ``where`` if it is not usable."""
        K, distortion = np.asarray(K, np.float64).reshape(3, 3), tuple(float(d) for d in distortion)
        if model.lower() not in DISTORTION_MODELS:
            raise SourceError(f"{where}: unsupported distortion model {model!r} (plumb_bob, radtan or equidistant)")
        model = DISTORTION_MODELS[model.lower()] if any(distortion) else "none"
        if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 or not all(map(math.isfinite, distortion)):
            raise SourceError(f"{where}: the calibration is not finite or has no positive focal length")
        if model == "equidistant" and len(distortion) != 4:
            raise SourceError(f"{where}: the equidistant model needs 4 coefficients, got {len(distortion)}")
        return Calibration(K, distortion, model, size)

    def to_metadata(self) -> dict:
        return {"K": self.K.tolist(), "distortion": list(self.distortion), "model": self.model, "size": list(self.size)}


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
