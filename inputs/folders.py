"""Dataset folders of image files: TUM RGB-D and EuRoC/ASL."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from deepslam.geometry import is_pose
from deepslam.inputs import parsing
from deepslam.inputs.calibration import Calibration, Rectifier
from deepslam.inputs.images import image_sizes, read_image, to_gray
from deepslam.inputs.source import SourceError, SourceFrame, SourceOptions, pipeline_size
from deepslam.inputs.timing import associate, check_order


class _ImageFolder:
    """A dataset folder of image files: ``stamps`` (ns), ``files``, ``truth`` {frame index: T_world_cam},
    ``rectify`` (set by the subclass)."""

    stamps: list[int]
    files: list[Path]
    truth: dict[int, np.ndarray]
    rectify: Rectifier

    def __len__(self) -> int:
        return len(self.files)

    @property
    def frames_with_truth(self) -> int:
        return len(self.truth)

    def frames(self) -> Iterator[SourceFrame]:
        for index, (stamp, path) in enumerate(zip(self.stamps, self.files, strict=True)):
            image = read_image(path)
            image = to_gray(image, "bgr8") if image.ndim == 3 else image
            yield SourceFrame(stamp, self.rectify(image), self.rectify.K, self.truth.get(index))


class TumFolder(_ImageFolder):
    """A TUM RGB-D folder: rgb.txt (timestamp, image file), groundtruth.txt (timestamp tx ty tz qx qy qz qw)
    if present. TUM folders carry no calibration: ``--calibration`` is needed."""

    kind = "TUM RGB-D folder"

    def __init__(self, root: Path, options: SourceOptions):
        self.root = root
        listing = root / "rgb.txt"
        rows = parsing.rows(listing, ("timestamp", "filename"))
        if not rows:
            raise SourceError(f"{listing}: no images listed")
        self.stamps = [parsing.seconds_ns(r[0], f"{listing} line {n}, timestamp") for n, r in rows]
        self.files = [parsing.inside(root, r[1], f"{listing} line {n}, filename") for n, r in rows]
        check_order(self.stamps, str(listing))
        self.truth = _associated(self.stamps, _tum_truth(root / "groundtruth.txt"))
        native = image_sizes(self.files)
        if options.calibration is None:
            raise SourceError(f"{root}: a TUM folder carries no calibration; give --calibration FILE")
        self.calibration = Calibration.from_yaml(options.calibration, native)
        self.rectify = Rectifier(self.calibration, pipeline_size(options.size))


def _tum_truth(path: Path) -> tuple[list[int], list[np.ndarray]]:
    """The stamps (ns) and poses of a TUM groundtruth.txt (timestamp tx ty tz qx qy qz qw), none if absent."""
    if not path.exists():
        return [], []
    fields = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
    rows = parsing.rows(path, fields)
    stamps = [parsing.seconds_ns(r[0], f"{path} line {n}, timestamp") for n, r in rows]
    return stamps, [parsing.pose(r[1:4], r[4:8], f"{path} line {n}") for n, r in rows]


def _associated(stamps: list[int], truth: tuple[list[int], list[np.ndarray]]) -> dict[int, np.ndarray]:
    """{frame index: true pose} by TUM's association of the truth's stamps to the images' ``stamps``."""
    truth_stamps, poses = truth
    return {i: poses[j] for i, j in associate(stamps, truth_stamps).items()}


class EurocFolder(_ImageFolder):
    """An EuRoC/ASL folder (``cam0/`` directly or under ``mav0/``): cam0/data.csv (timestamp ns, file),
    cam0/sensor.yaml (intrinsics, distortion, T_BS), and state_groundtruth_estimate0/data.csv (the body's
    pose) if present; the camera's pose is the body's times T_BS."""

    kind = "EuRoC/ASL folder"

    def __init__(self, root: Path, options: SourceOptions):
        base = root / "mav0" if (root / "mav0" / "cam0").is_dir() else root
        camera = base / "cam0"
        listing = camera / "data.csv"
        rows = parsing.rows(listing, ("timestamp", "filename"), separator=",")
        if not rows:
            raise SourceError(f"{listing}: no images listed")
        self.stamps = [parsing.nanoseconds(r[0], f"{listing} line {n}, timestamp") for n, r in rows]
        self.files = [parsing.inside(camera / "data", r[1], f"{listing} line {n}, filename") for n, r in rows]
        check_order(self.stamps, str(listing))
        native = image_sizes(self.files)
        sensor = _read_euroc_yaml(camera / "sensor.yaml")
        if options.calibration is not None:
            self.calibration = Calibration.from_yaml(options.calibration, native)
        else:
            fu, fv, cu, cv = parsing.yaml_numbers(sensor, "intrinsics", camera / "sensor.yaml", count=4)
            K = np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1]], np.float64)
            distortion = parsing.yaml_numbers(sensor, "distortion_coefficients", camera / "sensor.yaml")
            model = sensor.get("distortion_model", "none")
            self.calibration = Calibration.checked(K, distortion, str(model), native, camera / "sensor.yaml")
        T_BS = _body_to_sensor(sensor, camera / "sensor.yaml")
        truth = _euroc_truth(base / "state_groundtruth_estimate0" / "data.csv")
        self.truth = {i: T @ T_BS for i, T in _associated(self.stamps, truth).items()}
        self.rectify = Rectifier(self.calibration, pipeline_size(options.size))


def _euroc_truth(path: Path) -> tuple[list[int], list[np.ndarray]]:
    """The stamps (ns) and body poses of EuRoC's state_groundtruth_estimate0/data.csv (timestamp, p_RS_R x y
    z, q_RS w x y z, ...), none if absent."""
    if not path.exists():
        return [], []
    fields = ("timestamp", "p_x", "p_y", "p_z", "q_w", "q_x", "q_y", "q_z")
    rows = parsing.rows(path, fields, separator=",")
    stamps = [parsing.nanoseconds(r[0], f"{path} line {n}, timestamp") for n, r in rows]
    return stamps, [parsing.pose(r[1:4], [*r[5:8], r[4]], f"{path} line {n}") for n, r in rows]


def _body_to_sensor(sensor: dict, where: Path) -> np.ndarray:
    """EuRoC's T_BS (4, 4): the camera in the body frame (the identity if absent), a rigid transform."""
    if "T_BS" not in sensor:
        return np.eye(4)
    entry = sensor["T_BS"]
    if not isinstance(entry, dict):
        raise SourceError(f"{where}: T_BS must be a mapping with rows, cols and data, got {entry!r}")
    T = np.array(parsing.yaml_numbers(entry, "data", where, count=16)).reshape(4, 4)
    if not is_pose(T, tolerance=1e-3):
        raise SourceError(f"{where}: T_BS is not a rigid transform")
    return T


def _read_euroc_yaml(path: Path) -> dict:
    """EuRoC's sensor.yaml (a "%YAML:1.0" header that PyYAML does not take)."""
    try:
        text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("%YAML"))
    except (OSError, UnicodeDecodeError) as error:
        raise SourceError(f"{path}: cannot read it ({error})") from None
    return parsing.yaml_mapping(path, text)
