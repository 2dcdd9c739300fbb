"""What every input offers the pipeline (``Source``, ``SourceFrame``), how to read one (``SourceOptions``)
and ``open_source``, which tells the kinds apart."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Protocol

import numpy as np

from deepslam.errors import InputError

if TYPE_CHECKING:
    from deepslam.inputs.calibration import Calibration

MAX_SIDE = 2048  # the largest image side (px) the pipeline runs at
DEFAULT_SIZE = (120, 160)  # external images are resized to this (H, W) unless told otherwise


class SourceError(InputError):
    """An input the pipeline cannot run on; the message names what is wrong."""


@dataclass(frozen=True)
class SourceOptions:
    """How to read an input; every documented field is a ``deepslam replay`` option."""

    image_topic: str | None = field(default=None, metadata={"help": "bags: the image topic (default: the only one)"})
    camera_info_topic: str | None = field(
        default=None, metadata={"help": "bags: the CameraInfo topic (default: the only one, if any)"}
    )
    groundtruth_topic: str | None = field(
        default=None,
        metadata={"help": "bags: ground truth as PoseStamped, TransformStamped or nav_msgs/Odometry (default: none)"},
    )
    calibration: str | None = field(
        default=None,
        metadata={
            "help": "YAML with fx, fy, cx, cy and optionally distortion (a list), model (plumb_bob = radtan, or "
            "equidistant = fisheye), width and height (examples/calibration.yaml): the camera where the input "
            "carries none (it wins over the input's; not for deepslam logs)",
            "metavar": "FILE",
        },
    )
    fps: float | None = field(
        default=None,
        metadata={"help": "video files: frames per second (default: the container's)", "min": 0.001, "max": 1000},
    )
    size: tuple[int, int] | None = field(
        default=None,
        metadata={
            "help": "image size the pipeline runs at, multiples of 8 (default: a deepslam log's own, 120 160 for "
            "other inputs)",
            "metavar": ("H", "W"),
            "min": 8,
            "max": MAX_SIDE,
        },
    )

    def __post_init__(self):
        size = self.size
        if size is not None and (len(size) != 2 or min(size) < 8 or size[0] % 8 or size[1] % 8):
            raise SourceError(f"--size {' '.join(map(str, size))}: height and width must be multiples of 8")


@dataclass
class SourceFrame:
    """One frame ready for the odometry: stamp (ns), image uint8 (H, W), K (3, 3), ground truth or None."""

    stamp_ns: int
    image: np.ndarray
    K: np.ndarray
    T_world_cam: np.ndarray | None


class Source(Protocol):
    kind: str
    calibration: Calibration | None
    frames_with_truth: int

    def __len__(self) -> int: ...

    def frames(self) -> Iterator[SourceFrame]: ...


def pipeline_size(size: tuple[int, int] | None) -> tuple[int, int]:
    """The (H, W) the pipeline runs an input at: ``size`` (checked by ``SourceOptions``), or ``DEFAULT_SIZE``."""
    return size or DEFAULT_SIZE


def open_source(path: str | Path, options: SourceOptions = SourceOptions()) -> Source:
    """Recorded camera data, checked before any work starts.

    Args:
        path: a deepslam log, a ROS 2 bag (.mcap file or rosbag2 folder), a TUM RGB-D folder, an EuRoC/ASL
            folder or a video file, told apart by what they contain.
        options: topics, a calibration file, the size the pipeline runs at (``SourceOptions``).

    Returns:
        A ``Source``: ``len()``, ``kind``, ``calibration``, ``frames_with_truth`` and ``frames()``, an iterator
        of ``SourceFrame`` (stamp_ns, uint8 (H, W) image undistorted and resized, its K, true pose or None).
        ``SourceError`` (one line naming the file and what is wrong) for an input it cannot run on.
    """
    from deepslam.inputs.bags import RosBag
    from deepslam.inputs.video import VideoFile

    path = Path(path)
    kind = _kind(path, options)
    if options.fps is not None and kind is not VideoFile:
        raise SourceError(f"{path}: --fps applies to video files only (this {kind.kind} has its own stamps)")
    topics = _topics_given(options)
    if topics and kind is not RosBag:
        raise SourceError(f"{path}: --{topics[0].replace('_', '-')} applies to ROS 2 bags only, not to a {kind.kind}")
    return kind(path, options)


def _topics_given(options: SourceOptions) -> list[str]:
    """The names of the bag topic options ``options`` sets (image, camera info, ground truth)."""
    return [name for name in ("image_topic", "camera_info_topic", "groundtruth_topic") if getattr(options, name)]


def _kind(path: Path, options: SourceOptions) -> type:
    """The class that reads ``path``: told apart by what it contains (a deepslam log asked for topics is read as
    the ROS 2 bag it also is)."""
    from deepslam.inputs.bags import RosBag
    from deepslam.inputs.deepslam_log import DeepslamLog
    from deepslam.inputs.folders import EurocFolder, TumFolder
    from deepslam.inputs.video import VIDEO_SUFFIXES, VideoFile
    from deepslam.logs.reader import LogError, check_log, read_metadata

    if not path.exists():
        raise SourceError(f"{path}: no such file or folder")
    if path.is_dir():
        if (path / "rgb.txt").exists():
            return TumFolder
        if (path / "cam0" / "data.csv").exists() or (path / "mav0" / "cam0" / "data.csv").exists():
            return EurocFolder
        if (path / "metadata.yaml").exists():
            return RosBag
        raise SourceError(f"{path}: a folder that is neither a TUM RGB-D (rgb.txt), an EuRoC/ASL (cam0/data.csv) "
                          f"nor a rosbag2 folder (metadata.yaml)")  # fmt: skip
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return VideoFile
    try:
        check_log(path)
    except LogError as error:
        raise SourceError(str(error)) from None
    try:
        read_metadata(path)
        is_ours = not _topics_given(options)
    except LogError:
        is_ours = False
    return DeepslamLog if is_ours else RosBag
