"""deepslam's own logs as an input."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

from deepslam.inputs.calibration import Calibration, Rectifier
from deepslam.inputs.source import SourceError, SourceFrame, SourceOptions


class DeepslamLog:
    """A log written by ``deepslam run`` or ``replay``: its images (already undistorted), K, ground truth."""

    kind = "deepslam log"

    def __init__(self, path: Path, options: SourceOptions):
        from deepslam.logs.reader import read_frames

        if options.calibration is not None:
            raise SourceError(f"{path}: --calibration does not apply to a deepslam log (its frames carry their K)")
        self.path, self.read = path, read_frames
        self.count = self.frames_with_truth = 0
        for frame in read_frames(path):  # one pass: the camera from the first frame, how many have truth
            if not self.count:
                self.calibration = Calibration(frame.K, (), "none", frame.image.shape)
            self.count += 1
            self.frames_with_truth += frame.T_groundtruth is not None
        self.rectify = Rectifier(self.calibration, options.size) if options.size else None

    def __len__(self) -> int:
        return self.count

    def frames(self) -> Iterator[SourceFrame]:
        for f in self.read(self.path):
            if self.rectify is None:
                yield SourceFrame(f.stamp_ns, f.image, f.K, f.T_groundtruth)
            else:
                yield SourceFrame(f.stamp_ns, self.rectify(f.image), self.rectify.K, f.T_groundtruth)
