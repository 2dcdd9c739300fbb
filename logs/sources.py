"""Camera data from outside: ROS 2 bags, TUM RGB-D and EuRoC/ASL folders, deepslam's own logs.

``open_source(path, options)`` recognises what ``path`` is, checks it before any work starts (topics,
encodings, calibration, timestamps in order, one image size), and yields ``SourceFrame``s: grayscale
images undistorted (plumb_bob / radtan or equidistant, with OpenCV) and resized to the pipeline's size,
with the K that goes with them, and ground truth where the input has it (associated by time, within
``MAX_TIME_GAP_NS``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Protocol

import cv2
import numpy as np
import yaml

from deepslam.logs.frames import pose_matrix

MAX_TIME_GAP_NS = 20_000_000  # ground truth further than this from an image is not associated (TUM's 0.02 s)
DEFAULT_SIZE = (120, 160)  # external images are resized to this (H, W) unless told otherwise
RAW_ENCODINGS = {"mono8": (1, np.uint8), "mono16": (1, np.uint16), "rgb8": (3, np.uint8), "bgr8": (3, np.uint8),
                 "rgba8": (4, np.uint8), "bgra8": (4, np.uint8)}  # fmt: skip
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry")
DISTORTION_MODELS = {"plumb_bob": "plumb_bob", "radtan": "plumb_bob", "radial-tangential": "plumb_bob",
                     "rational_polynomial": "plumb_bob", "equidistant": "equidistant", "fisheye": "equidistant",
                     "none": "none", "": "none"}  # fmt: skip


class SourceError(ValueError):
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
            "help": "YAML with fx, fy, cx, cy and optionally distortion (a list), model (plumb_bob or equidistant), "
            "width and height: the camera's calibration where the input carries none (it wins over the input's)",
            "metavar": "FILE",
        },
    )
    size: tuple[int, int] | None = field(
        default=None,
        metadata={
            "help": "image size the pipeline runs at, multiples of 8 (default: a deepslam log's own, 120 160 for "
            "other inputs)",
            "metavar": ("H", "W"),
            "min": 8,
        },
    )


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


def to_gray(image: np.ndarray, encoding: str) -> np.ndarray:
    """uint8 (H, W) of a decoded image in one of ``RAW_ENCODINGS`` (mono16 is scaled by 1/256)."""
    if encoding == "mono16":
        return (image >> 8).astype(np.uint8)
    if image.ndim == 2:
        return image
    code = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY,
            "bgra8": cv2.COLOR_BGRA2GRAY}[encoding]  # fmt: skip
    return cv2.cvtColor(image, code)


def _pipeline_size(size: tuple[int, int] | None, native: tuple[int, int]) -> tuple[int, int]:
    chosen = size or DEFAULT_SIZE
    if chosen[0] % 8 or chosen[1] % 8:
        raise SourceError(f"--size {chosen[0]} {chosen[1]}: height and width must be multiples of 8")
    return chosen


def _check_order(stamps: list[int], what: str) -> None:
    for index, (a, b) in enumerate(zip(stamps, stamps[1:], strict=False)):
        if b <= a:
            raise SourceError(f"{what}: timestamps out of order at frame {index + 1} ({a} then {b} ns)")


def associate(stamps: list[int], truth_stamps: list[int], max_gap_ns: int = MAX_TIME_GAP_NS) -> dict[int, int]:
    """TUM's association: pairs (image i, truth j) closest in time first, each used once, within
    ``max_gap_ns``; returns {i: j}."""
    if not stamps or not truth_stamps:
        return {}
    truth = np.asarray(truth_stamps, np.int64)
    candidates = []
    for i, t in enumerate(stamps):
        near = np.nonzero(np.abs(truth - t) < max_gap_ns)[0]
        candidates += [(abs(int(truth[j]) - t), i, int(j)) for j in near]
    pairs, used = {}, set()
    for _, i, j in sorted(candidates):
        if i not in pairs and j not in used:
            pairs[i] = j
            used.add(j)
    return pairs


# ---------------------------------------------------------------- TUM RGB-D


def _read_lines(path: Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]


def _seconds_to_ns(text: str) -> int:
    whole, _, fraction = text.partition(".")
    return int(whole) * 1_000_000_000 + int((fraction + "000000000")[:9])  # exact: no float rounding


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
            image = _read_image(path)
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
        self.stamps = [_seconds_to_ns(r[0]) for r in rows]
        self.files = [root / r[1] for r in rows]
        _check_order(self.stamps, str(root / "rgb.txt"))
        self.truth: dict[int, np.ndarray] = {}
        if (root / "groundtruth.txt").exists():
            truth = [(_seconds_to_ns(r[0]), [float(v) for v in r[1:8]]) for r in _read_lines(root / "groundtruth.txt")]
            pairs = associate(self.stamps, [t for t, _ in truth])
            self.truth = {
                i: pose_matrix(np.array(truth[j][1][:3]), np.array(truth[j][1][3:])) for i, j in pairs.items()
            }
        native = _image_sizes(self.files)
        if options.calibration is None:
            raise SourceError(f"{root}: a TUM folder carries no calibration; give --calibration FILE")
        self.calibration = Calibration.from_yaml(options.calibration, native)
        self.rectify = Rectifier(self.calibration, _pipeline_size(options.size, native))


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SourceError(f"{path}: cannot read the image")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    return image[..., :3] if image.ndim == 3 else image


def _image_sizes(files: list[Path]) -> tuple[int, int]:
    """The one (H, W) of all ``files``; SourceError if one is missing, unreadable or of another size."""
    size = None
    for path in files:
        if not path.exists():
            raise SourceError(f"{path}: no such image")
        shape = _read_image(path).shape[:2]
        if size is not None and shape != size:
            raise SourceError(f"{path}: images change size ({size[0]}x{size[1]} then {shape[0]}x{shape[1]})")
        size = shape
    return size


# ---------------------------------------------------------------- EuRoC / ASL


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
        _check_order(self.stamps, str(camera / "data.csv"))
        native = _image_sizes(self.files)
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
        self.rectify = Rectifier(self.calibration, _pipeline_size(options.size, native))

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


# ---------------------------------------------------------------- ROS 2 bags


class RosBag:
    """A ROS 2 bag (a bare .mcap file or a rosbag2 folder), read with rosbags' standard typestore."""

    kind = "ROS 2 bag"

    def __init__(self, path: Path, options: SourceOptions):
        from rosbags.highlevel import AnyReader

        self.path, self.options = path, options
        self.reader = AnyReader([path])
        try:
            self.reader.open()
        except Exception as error:  # noqa: BLE001 - rosbags raises its own kinds for any unreadable bag
            raise SourceError(f"{path}: not a readable ROS 2 bag ({error})") from None
        topics = {c.topic: c.msgtype for c in self.reader.connections}
        self.image_topic = self._topic(options.image_topic, IMAGE_TYPES, topics, "image", required=True)
        self.info_topic = self._topic(options.camera_info_topic, ("sensor_msgs/msg/CameraInfo",), topics,
                                      "camera info", required=False)  # fmt: skip
        self.truth_topic = (
            self._topic(options.groundtruth_topic, POSE_TYPES, topics, "ground truth", required=True)
            if options.groundtruth_topic
            else None
        )
        self.stamps, native = self._scan_images()
        self.calibration = self._calibration(native)
        self.rectify = Rectifier(self.calibration, _pipeline_size(options.size, native))
        self.truth = self._truth()

    def _topic(self, wanted: str | None, types: tuple[str, ...], topics: dict, what: str, required: bool) -> str | None:
        listed = ", ".join(f"{t} ({k})" for t, k in sorted(topics.items()))
        if wanted is not None:
            if wanted not in topics:
                raise SourceError(f"{self.path}: no topic {wanted}; the bag has {listed}")
            if topics[wanted] not in types:
                raise SourceError(f"{self.path}: {wanted} is a {topics[wanted]}, not one of {', '.join(types)}")
            return wanted
        matching = [t for t, k in topics.items() if k in types]
        if len(matching) == 1:
            return matching[0]
        if matching or required:
            which = "several" if matching else "no"
            raise SourceError(f"{self.path}: {which} {what} topics; choose one with --{what.replace(' ', '-')}-topic "
                              f"(the bag has {listed})")  # fmt: skip
        return None

    def _messages(self, topic: str):
        connections = [c for c in self.reader.connections if c.topic == topic]
        for connection, log_time, raw in self.reader.messages(connections=connections):
            yield connection, log_time, self.reader.deserialize(raw, connection.msgtype)

    @staticmethod
    def _stamp(message, log_time: int) -> int:
        header = getattr(message, "header", None)
        stamp = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec if header is not None else 0
        return stamp or log_time

    def _image(self, connection, message) -> np.ndarray:
        if connection.msgtype.endswith("CompressedImage"):
            image = cv2.imdecode(np.frombuffer(bytes(message.data), np.uint8), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise SourceError(f"{self.path}: a {message.format!r} image on {connection.topic} does not decode")
            if image.dtype == np.uint16:
                image = (image >> 8).astype(np.uint8)
            return image if image.ndim == 2 else to_gray(image, "bgr8" if image.shape[2] == 3 else "bgra8")
        if message.encoding not in RAW_ENCODINGS:
            raise SourceError(f"{self.path}: {connection.topic} has the unsupported encoding {message.encoding!r} "
                              f"(supported: {', '.join(RAW_ENCODINGS)})")  # fmt: skip
        channels, dtype = RAW_ENCODINGS[message.encoding]
        data = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
        pixels = data[:, : message.width * channels * np.dtype(dtype).itemsize].copy().view(dtype)
        if message.is_bigendian and dtype == np.uint16:
            pixels = pixels.byteswap()
        return to_gray(pixels.reshape(message.height, message.width, channels).squeeze(-1) if channels == 1
                       else pixels.reshape(message.height, message.width, channels), message.encoding)  # fmt: skip

    def _scan_images(self) -> tuple[list[int], tuple[int, int]]:
        """Every image's stamp, checked in order and of one size, before any work."""
        stamps, size = [], None
        for connection, log_time, message in self._messages(self.image_topic):
            shape = self._image(connection, message).shape
            if size is not None and shape != size:
                raise SourceError(f"{self.path}: images on {self.image_topic} change size "
                                  f"({size[0]}x{size[1]} then {shape[0]}x{shape[1]})")  # fmt: skip
            size = shape
            stamps.append(self._stamp(message, log_time))
        if not stamps:
            raise SourceError(f"{self.path}: no messages on {self.image_topic}")
        _check_order(stamps, f"{self.path} {self.image_topic}")
        return stamps, size

    def _calibration(self, native: tuple[int, int]) -> Calibration:
        if self.options.calibration is not None:
            return Calibration.from_yaml(self.options.calibration, native)
        if self.info_topic is None:
            raise SourceError(f"{self.path}: no CameraInfo topic and no --calibration: the camera is unknown")
        for _, _, info in self._messages(self.info_topic):
            if (info.height, info.width) != native and info.height:
                raise SourceError(f"{self.path}: {self.info_topic} is for {info.height}x{info.width} images, "
                                  f"{self.image_topic} has {native[0]}x{native[1]}")  # fmt: skip
            return Calibration.checked(info.k, list(info.d), info.distortion_model, native, self.info_topic)
        raise SourceError(f"{self.path}: no messages on {self.info_topic}")

    def _truth(self) -> dict[int, np.ndarray]:
        if self.truth_topic is None:
            return {}
        stamps, poses = [], []
        for _, log_time, message in self._messages(self.truth_topic):
            stamps.append(self._stamp(message, log_time))
            poses.append(_pose_of(message))
        return {i: poses[j] for i, j in associate(self.stamps, stamps).items()}

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def frames_with_truth(self) -> int:
        return len(self.truth)

    def frames(self) -> Iterator[SourceFrame]:
        for index, (connection, _, message) in enumerate(self._messages(self.image_topic)):
            image = self.rectify(self._image(connection, message))
            yield SourceFrame(self.stamps[index], image, self.rectify.K, self.truth.get(index))


def _pose_of(message) -> np.ndarray:
    """T_world_cam of a PoseStamped, TransformStamped or Odometry message."""
    if hasattr(message, "transform"):
        t, q = message.transform.translation, message.transform.rotation
    else:
        pose = message.pose.pose if hasattr(message.pose, "pose") else message.pose
        t, q = pose.position, pose.orientation
    return pose_matrix(np.array([t.x, t.y, t.z]), np.array([q.x, q.y, q.z, q.w]))


# ---------------------------------------------------------------- deepslam logs


class DeepslamLog:
    """A log written by ``deepslam run`` or ``replay``: its images (already undistorted), K, ground truth."""

    kind = "deepslam log"

    def __init__(self, path: Path, options: SourceOptions):
        from deepslam.logs.reader import read_frames

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


def open_source(path: str | Path, options: SourceOptions = SourceOptions()) -> Source:
    """The input at ``path`` as a checked ``Source``: a deepslam log, a ROS 2 bag (.mcap file or rosbag2
    folder), a TUM RGB-D folder or an EuRoC/ASL folder, told apart by what they contain."""
    from deepslam.logs.reader import LogError, check_log, read_metadata

    path = Path(path)
    if not path.exists():
        raise SourceError(f"{path}: no such file or folder")
    if path.is_dir():
        if (path / "rgb.txt").exists():
            return TumFolder(path, options)
        if (path / "cam0" / "data.csv").exists() or (path / "mav0" / "cam0" / "data.csv").exists():
            return EurocFolder(path, options)
        if (path / "metadata.yaml").exists():
            return RosBag(path, options)
        raise SourceError(f"{path}: a folder that is neither a TUM RGB-D (rgb.txt), an EuRoC/ASL (cam0/data.csv) "
                          f"nor a rosbag2 folder (metadata.yaml)")  # fmt: skip
    try:
        check_log(path)
    except LogError as error:
        raise SourceError(str(error)) from None
    try:
        read_metadata(path)
        is_ours = not any((options.image_topic, options.camera_info_topic, options.groundtruth_topic))
    except LogError:
        is_ours = False
    return DeepslamLog(path, options) if is_ours else RosBag(path, options)
