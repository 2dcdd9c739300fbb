"""Dataset folders of image files: TUM RGB-D and EuRoC/ASL."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np
import yaml

from deepslam.geometry import pose_matrix
from deepslam.inputs.calibration import Calibration, Rectifier
from deepslam.inputs.images import image_sizes, read_image, to_gray
from deepslam.inputs.source import SourceError, SourceFrame, SourceOptions, pipeline_size
from deepslam.inputs.timing import associate, check_order, seconds_to_ns


def _read_lines(path: Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]


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
        rows = _read_lines(root / "rgb.txt")
        if not rows:
            raise SourceError(f"{root / 'rgb.txt'}: no images listed")
        self.stamps = [seconds_to_ns(r[0]) for r in rows]
        self.files = [root / r[1] for r in rows]
        check_order(self.stamps, str(root / "rgb.txt"))
        self.truth: dict[int, np.ndarray] = {}
        if (root / "groundtruth.txt").exists():
            truth = [(seconds_to_ns(r[0]), [float(v) for v in r[1:8]]) for r in _read_lines(root / "groundtruth.txt")]
            pairs = associate(self.stamps, [t for t, _ in truth])
            self.truth = {
                i: pose_matrix(np.array(truth[j][1][:3]), np.array(truth[j][1][3:])) for i, j in pairs.items()
            }
        native = image_sizes(self.files)
        if options.calibration is None:
            raise SourceError(f"{root}: a TUM folder carries no calibration; give --calibration FILE")
        self.calibration = Calibration.from_yaml(options.calibration, native)
        self.rectify = Rectifier(self.calibration, pipeline_size(options.size, native))


class EurocFolder(_ImageFolder):
    """An EuRoC/ASL folder (``cam0/`` directly or under ``mav0/``): cam0/data.csv (timestamp ns, file),
    cam0/sensor.yaml (intrinsics, distortion, T_BS), and state_groundtruth_estimate0/data.csv (the body's
    pose) if present; the camera's pose is the body's times T_BS."""

    kind = "EuRoC/ASL folder"

    def __init__(self, root: Path, options: SourceOptions):
        base = root / "mav0" if (root / "mav0" / "cam0").is_dir() else root
        camera = base / "cam0"
        rows = [r.split(",") for r in (camera / "data.csv").read_text().splitlines() if r and not r.startswith("#")]
        self.stamps = [int(r[0]) for r in rows]
        self.files = [camera / "data" / r[1].strip() for r in rows]
        if not self.files:
            raise SourceError(f"{camera / 'data.csv'}: no images listed")
        check_order(self.stamps, str(camera / "data.csv"))
        native = image_sizes(self.files)
        sensor = _read_euroc_yaml(camera / "sensor.yaml")
        T_BS = np.asarray(sensor.get("T_BS", {}).get("data", np.eye(4).ravel()), np.float64).reshape(4, 4)
        if options.calibration is not None:
            self.calibration = Calibration.from_yaml(options.calibration, native)
        else:
            try:
                fu, fv, cu, cv = (float(v) for v in sensor["intrinsics"])
            except (KeyError, TypeError, ValueError):
                raise SourceError(f"{camera / 'sensor.yaml'}: intrinsics must be four numbers fu, fv, cu, cv") from None
            K = np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1]], np.float64)
            self.calibration = Calibration.checked(
                K, sensor.get("distortion_coefficients", []), str(sensor.get("distortion_model", "none")), native,
                camera / "sensor.yaml",
            )  # fmt: skip
        self.truth = self._truth(base / "state_groundtruth_estimate0" / "data.csv", T_BS)
        self.rectify = Rectifier(self.calibration, pipeline_size(options.size, native))

    def _truth(self, path: Path, T_BS: np.ndarray) -> dict[int, np.ndarray]:
        if not path.exists():
            return {}
        rows = [[float(v) for v in r.split(",")[:8]] for r in path.read_text().splitlines() if r and r[0] != "#"]
        stamps = [int(r.split(",")[0]) for r in path.read_text().splitlines() if r and r[0] != "#"]
        pairs = associate(self.stamps, stamps)
        # EuRoC: p_RS_R x y z, then q_RS w x y z
        poses = {j: pose_matrix(np.array(rows[j][1:4]), np.array([*rows[j][5:8], rows[j][4]])) for j in pairs.values()}
        return {i: poses[j] @ T_BS for i, j in pairs.items()}


def _read_euroc_yaml(path: Path) -> dict:
    """EuRoC's sensor.yaml (a "%YAML:1.0" header that PyYAML does not take)."""
    text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("%YAML"))
    try:
        return yaml.safe_load(text) or {}
    except yaml.YAMLError as error:
        raise SourceError(f"{path}: cannot read it ({error})") from None
