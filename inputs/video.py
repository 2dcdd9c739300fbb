"""Video files (MP4, AVI, MOV, MKV, WebM, ...) as an input, read with OpenCV: a calibration file gives the
camera, the container's frame rate (or ``--fps``) the stamps."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import cv2

from deepslam.inputs.calibration import Calibration, Rectifier
from deepslam.inputs.images import to_gray
from deepslam.inputs.source import SourceError, SourceFrame, SourceOptions, pipeline_size
from deepslam.logs.images import MAX_PIXELS, too_large

VIDEO_SUFFIXES = (".mp4", ".m4v", ".avi", ".mov", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv")


class VideoFile:
    """A video file: every frame in order, grayscale, ``1 / fps`` seconds apart from 0; no ground truth."""

    kind = "video file"
    frames_with_truth = 0

    def __init__(self, path: Path, options: SourceOptions):
        self.path = path
        capture = self._open()
        native = (int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)), int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)))
        container_fps = capture.get(cv2.CAP_PROP_FPS)
        capture.release()
        if min(native) < 1 or too_large(native):
            raise SourceError(f"{path}: a video of {native[0]}x{native[1]} frames (at most {MAX_PIXELS} pixels)")
        self.fps = options.fps or (container_fps if 0 < container_fps <= 1000 else None)
        if self.fps is None:
            raise SourceError(f"{path}: the video does not say its frame rate; give --fps")
        if options.calibration is None:
            raise SourceError(f"{path}: a video carries no calibration; give --calibration FILE")
        self.calibration = Calibration.from_yaml(options.calibration, native)
        self.rectify = Rectifier(self.calibration, pipeline_size(options.size))
        self.count = sum(1 for _ in self._images())  # decoded once before any work: the length, and no surprise

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            raise SourceError(f"{self.path}: OpenCV cannot read this video")
        return capture

    def _images(self) -> Iterator:
        capture = self._open()
        try:
            while True:
                ok, image = capture.read()
                if not ok:
                    return
                yield image
        finally:
            capture.release()

    def __len__(self) -> int:
        return self.count

    def frames(self) -> Iterator[SourceFrame]:
        for index, image in enumerate(self._images()):
            gray = image if image.ndim == 2 else to_gray(image, "bgr8")
            yield SourceFrame(round(index * 1e9 / self.fps), self.rectify(gray), self.rectify.K, None)
