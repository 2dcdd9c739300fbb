"""ROS 2 bags (a bare .mcap file or a rosbag2 folder), read with rosbags' standard typestore."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from deepslam.inputs import parsing
from deepslam.inputs.calibration import Calibration, Rectifier
from deepslam.inputs.images import RAW_ENCODINGS, to_gray
from deepslam.inputs.source import SourceError, SourceFrame, SourceOptions, pipeline_size
from deepslam.inputs.timing import associate, check_order
from deepslam.logs.images import MAX_PIXELS, encoded_size, too_large

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry")


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
        try:
            self._check()
        finally:
            self.reader.close()  # frames() reads with a reader of its own

    def _check(self) -> None:
        """Choose the topics, and read every image's stamp, the camera and the ground truth, before any work."""
        options, topics = self.options, {c.topic: c.msgtype for c in self.reader.connections}
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
        self.rectify = Rectifier(self.calibration, pipeline_size(options.size))
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

    @staticmethod
    def _stamp(message, log_time: int) -> int:
        header = getattr(message, "header", None)
        stamp = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec if header is not None else 0
        return stamp or log_time

    def _image(self, connection, message) -> np.ndarray:
        if connection.msgtype.endswith("CompressedImage"):
            size = encoded_size(bytes(message.data[:65536]))
            if too_large(size):
                raise SourceError(f"{self.path}: a {size[0]}x{size[1]} image on {connection.topic} is over the "
                                  f"{MAX_PIXELS} pixels an input may hold")  # fmt: skip
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
        row = message.width * channels * np.dtype(dtype).itemsize
        if (
            min(message.height, message.width) < 1
            or too_large((message.height, message.width))
            or message.step < row
            or len(message.data) != message.height * message.step
        ):
            raise SourceError(f"{self.path}: a {message.height}x{message.width} image on {connection.topic} with "
                              f"{len(message.data)} bytes is too large or not as its header says")  # fmt: skip
        data = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
        pixels = data[:, :row].copy().view(dtype)
        if message.is_bigendian and dtype == np.uint16:
            pixels = pixels.byteswap()
        return to_gray(pixels.reshape(message.height, message.width, channels).squeeze(-1) if channels == 1
                       else pixels.reshape(message.height, message.width, channels), message.encoding)  # fmt: skip

    def _scan_images(self) -> tuple[list[int], tuple[int, int]]:
        """Every image's stamp, checked in order and of one size, before any work."""
        stamps, size = [], None
        for connection, log_time, message in _messages(self.reader, self.image_topic):
            shape = self._image(connection, message).shape
            if size is not None and shape != size:
                raise SourceError(f"{self.path}: images on {self.image_topic} change size "
                                  f"({size[0]}x{size[1]} then {shape[0]}x{shape[1]})")  # fmt: skip
            size = shape
            stamps.append(self._stamp(message, log_time))
        if not stamps:
            raise SourceError(f"{self.path}: no messages on {self.image_topic}")
        check_order(stamps, f"{self.path} {self.image_topic}")
        return stamps, size

    def _calibration(self, native: tuple[int, int]) -> Calibration:
        if self.options.calibration is not None:
            return Calibration.from_yaml(self.options.calibration, native)
        if self.info_topic is None:
            raise SourceError(f"{self.path}: no CameraInfo topic and no --calibration: the camera is unknown")
        for _, _, info in _messages(self.reader, self.info_topic):
            if (info.height, info.width) != native and info.height:
                raise SourceError(f"{self.path}: {self.info_topic} is for {info.height}x{info.width} images, "
                                  f"{self.image_topic} has {native[0]}x{native[1]}")  # fmt: skip
            return Calibration.checked(
                info.k, list(info.d), info.distortion_model, native, f"{self.path} {self.info_topic}"
            )
        raise SourceError(f"{self.path}: no messages on {self.info_topic}")

    def _truth(self) -> dict[int, np.ndarray]:
        if self.truth_topic is None:
            return {}
        stamps, poses = [], []
        for _, log_time, message in _messages(self.reader, self.truth_topic):
            stamps.append(self._stamp(message, log_time))
            poses.append(_pose_of(message, f"{self.path} {self.truth_topic} at {stamps[-1]} ns"))
        return {i: poses[j] for i, j in associate(self.stamps, stamps).items()}

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def frames_with_truth(self) -> int:
        return len(self.truth)

    def frames(self) -> Iterator[SourceFrame]:
        """The frames, read by a reader of their own, open while they are read (so several may read at once)."""
        from rosbags.highlevel import AnyReader

        reader = AnyReader([self.path])
        reader.open()
        try:
            for index, (connection, _, message) in enumerate(_messages(reader, self.image_topic)):
                image = self.rectify(self._image(connection, message))
                yield SourceFrame(self.stamps[index], image, self.rectify.K, self.truth.get(index))
        finally:
            reader.close()


def _messages(reader, topic: str):
    """(connection, log time (ns), message) of every message on ``topic`` of the open rosbags ``reader``."""
    connections = [c for c in reader.connections if c.topic == topic]
    for connection, log_time, raw in reader.messages(connections=connections):
        yield connection, log_time, reader.deserialize(raw, connection.msgtype)


def _pose_of(message, where: str) -> np.ndarray:
    """T_world_cam of a PoseStamped, TransformStamped or Odometry message (finite, a unit quaternion)."""
    if hasattr(message, "transform"):
        t, q = message.transform.translation, message.transform.rotation
    else:
        pose = message.pose.pose if hasattr(message.pose, "pose") else message.pose
        t, q = pose.position, pose.orientation
    return parsing.pose([t.x, t.y, t.z], [q.x, q.y, q.z, q.w], where)
