"""Writing runs to MCAP as ROS 2 messages (CDR), chunk by chunk as the run goes.

A log in progress is ``OUT.partial`` beside ``OUT``, locked against a second writer and flushed after
every frame, so a run that is killed leaves a file readable up to its last complete chunk
(``deepslam recover`` finishes it). When the run ends, normally or by Ctrl-C / SIGTERM (the context
manager), the summary is written and the file renamed to ``OUT``; a run that fails keeps its frames in
``OUT.partial`` and leaves any existing ``OUT`` untouched.
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

import cv2
import numpy as np
from mcap.writer import CompressionType
from mcap_ros2.writer import Writer as Ros2Writer

from deepslam.errors import InputError
from deepslam.files import OutputError, check_output, partial_path
from deepslam.geometry import quaternion_from_matrix
from deepslam.interrupts import held_signals
from deepslam.logs.frames import LogFrame
from deepslam.logs.schemas import (
    CAMERA_FRAME,
    GROUNDTRUTH_FRAME,
    METADATA_CHECKSUM,
    SUMMARY_RECORD,
    TOPICS,
    WORLD_FRAME,
    metadata_checksum,
    msgdef,
    ros2_name,
)

PATH_POSES_AT_KEYFRAMES = 200  # poses of each path published at a keyframe (the whole path at the end)
TRACK_AGE_SCALE = 20  # frames over which a track's colour goes from new to old
_CLEAR = {"r": 0.0, "g": 0.0, "b": 0.0, "a": 0.0}


def _time(stamp_ns: int) -> dict:
    return {"sec": int(stamp_ns // 1_000_000_000), "nanosec": int(stamp_ns % 1_000_000_000)}


def _header(stamp_ns: int, frame_id: str) -> dict:
    return {"stamp": _time(stamp_ns), "frame_id": frame_id}


def _pose(T: np.ndarray) -> dict:
    x, y, z, w = quaternion_from_matrix(T[:3, :3])
    px, py, pz = (float(v) for v in T[:3, 3])
    return {"position": {"x": px, "y": py, "z": pz}, "orientation": {"x": x, "y": y, "z": z, "w": w}}


def _transform(T: np.ndarray) -> dict:
    pose = _pose(T)
    return {"translation": pose["position"], "rotation": pose["orientation"]}


def ros_covariance(covariance: np.ndarray, T: np.ndarray) -> list[float]:
    """gtsam's body-frame (rotation, translation) covariance as ROS's (x, y, z, rx, ry, rz) in the
    world frame's axes (both blocks rotated by the pose's rotation)."""
    order = [3, 4, 5, 0, 1, 2]
    rotate = np.kron(np.eye(2), T[:3, :3])
    return (rotate @ np.asarray(covariance)[np.ix_(order, order)] @ rotate.T).ravel().tolist()


LogWriteError = OutputError  # the name this module gave it


def _open_locked(partial: Path, path: Path, tries: int = 3) -> int:
    """A descriptor of ``partial``, created if missing, under an exclusive lock, and still the file that
    bears that name once locked: a run that finished between our open and our lock renamed the file we
    opened to its log, which must not be truncated (then we open the name again)."""
    for _ in range(tries):
        descriptor = os.open(partial, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(descriptor)
            raise LogWriteError(f"{path} is being written by another run ({partial} is locked)") from None
        try:
            named = os.stat(partial)
        except FileNotFoundError:
            named = None
        opened = os.fstat(descriptor)
        if named is not None and (named.st_dev, named.st_ino) == (opened.st_dev, opened.st_ino):
            return descriptor
        os.close(descriptor)  # renamed away (a run that just finished): its file is not ours to truncate
    raise LogWriteError(f"{path} keeps being written by other runs; try again")


class LogWriter:
    """A run's MCAP log of ROS 2 messages, written frame by frame.

    ``with LogWriter(path, metadata) as log: log.write(frame)`` for each ``LogFrame``: the file grows as
    ``path.partial`` (locked against a second writer) and becomes ``path`` when the block ends normally or by
    Ctrl-C / SIGTERM; a failed run leaves ``path`` as it was.

    Args:
        path: the log to write (not a folder, not an input of the run).
        metadata: the run's settings, stored as JSON in the "deepslam" metadata record.
        chunk_size: bytes of messages per zstd-compressed chunk.
    """

    def __init__(self, path: str | Path, metadata: dict, chunk_size: int = 256 * 1024):
        check_output(path)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.partial = partial_path(self.path)
        descriptor = _open_locked(self.partial, self.path)
        os.ftruncate(descriptor, 0)
        self._file = os.fdopen(descriptor, "wb")
        self._writer = Ros2Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._schemas = {
            topic: self._writer.register_msgdef(ros2_name(kind), msgdef(kind)) for topic, kind in TOPICS.items()
        }
        self._add_metadata("deepslam", metadata)
        self.frames = 0
        self._first_seen: dict[int, int] = {}  # track id -> the frame it was first logged in (live tracks only)
        self._paths: dict[str, list[tuple[int, np.ndarray]]] = {"/estimate/path": [], "/groundtruth/path": []}
        self._keyframes: list[tuple[int, np.ndarray]] = []  # (stamp, T_estimate) of every keyframe

    def _put(self, topic: str, message: dict, stamp_ns: int) -> None:
        self._writer.write_message(
            topic, self._schemas[topic], message, log_time=stamp_ns, publish_time=stamp_ns, sequence=self.frames
        )

    def write(self, frame: LogFrame) -> None:
        """Write every topic of one frame (those whose data the frame has); Ctrl-C waits for the whole frame.
        An ``OSError`` (a full disk) names the partial log, which keeps the frames written before it."""
        with held_signals():
            try:
                self._write(frame)
            except OSError as error:
                note = f" ({self.frames} whole frames kept: deepslam recover {self.partial} --out FILE)"
                raise OSError(error.errno, (error.strerror or str(error)) + note, str(self.partial)) from None

    def _write(self, frame: LogFrame) -> None:
        """One frame's messages, topic by topic in a fixed order (each built by its own function)."""
        t = frame.stamp_ns
        self._put("/camera/image", _image_message(frame), t)
        self._put("/camera/camera_info", _camera_info_message(frame), t)
        if frame.T_groundtruth is not None:
            self._put("/groundtruth/pose", {"header": _header(t, WORLD_FRAME), "pose": _pose(frame.T_groundtruth)}, t)
        if frame.T_estimate is not None:
            self._put("/estimate/pose", {"header": _header(t, WORLD_FRAME), "pose": _pose(frame.T_estimate)}, t)
            if frame.covariance is not None:
                self._put("/estimate/pose_covariance", _covariance_message(frame), t)
        transforms = _transforms(frame)
        if transforms:
            self._put("/tf", {"transforms": transforms}, t)
        if frame.tracks is not None:
            self._put("/frontend/tracks", _tracks_message(frame), t)
        if frame.correspondences is not None:
            self._put("/frontend/correspondences", _correspondences_message(frame), t)
        if frame.tracks is not None:
            self._put(
                "/camera/annotations", self._annotations(t, np.asarray(frame.tracks, np.float64).reshape(-1, 4)), t
            )
        for topic, pose in (("/estimate/path", frame.T_estimate), ("/groundtruth/path", frame.T_groundtruth)):
            if pose is not None:
                self._paths[topic].append((t, pose))
        if frame.diagnostics is not None and frame.diagnostics.keyframe:
            self._put_paths(t, PATH_POSES_AT_KEYFRAMES)
            if frame.T_estimate is not None:
                self._keyframes.append((t, frame.T_estimate))
                self._put_keyframes(t, PATH_POSES_AT_KEYFRAMES)
        if frame.landmarks is not None:
            self._put("/map/landmarks", _point_cloud(t, frame.landmarks), t)
        if frame.diagnostics is not None:
            self._put("/diagnostics/frame", _diagnostics_message(frame), t)
        self.frames += 1
        self._file.flush()

    def add_summary(self, figures: dict) -> None:
        """The run's figures (``RunOutput.summary``) as the metadata record "deepslam_summary", checksummed
        like the run's settings (``read_metadata(path, "deepslam_summary")`` reads it)."""
        self._add_metadata(SUMMARY_RECORD, figures)

    def _add_metadata(self, name: str, values: dict) -> None:
        """A metadata record: text as it is, other values as JSON, and a checksum over them."""
        entries = {k: v if isinstance(v, str) else json.dumps(v) for k, v in values.items()}
        self._writer.add_metadata(name, entries | {METADATA_CHECKSUM: metadata_checksum(entries)})

    def _annotations(self, stamp_ns: int, tracks: np.ndarray) -> dict:
        """Foxglove ``ImageAnnotations`` of one frame's tracks: a dot per point coloured by the track's age
        (new: yellow, 20 frames or more: blue), a ring around tracks carried without a detection (score 0).
        Foxglove puts the pixel origin at the top-left corner of the first pixel, ours at its centre."""
        ids = tracks[:, 3].astype(np.int64)
        self._first_seen = {i: self._first_seen.get(i, self.frames) for i in ids.tolist()}
        ages = np.array([self.frames - self._first_seen[i] for i in ids.tolist()], np.float64)
        shade = np.clip(ages / TRACK_AGE_SCALE, 0.0, 1.0)
        time = _time(stamp_ns)
        points = [{"x": float(x) + 0.5, "y": float(y) + 0.5} for x, y in tracks[:, :2]]
        colours = [{"r": 1.0 - s, "g": 0.85 - 0.45 * s, "b": s, "a": 1.0} for s in shade]
        carried = tracks[:, 2] == 0
        rings = [
            {"timestamp": time, "position": point, "diameter": 6.0, "thickness": 1.0,
             "fill_color": _CLEAR, "outline_color": {"r": 1.0, "g": 0.2, "b": 0.2, "a": 1.0}}
            for point, is_carried in zip(points, carried, strict=True) if is_carried
        ]  # fmt: skip
        dots = {"timestamp": time, "type": 1, "points": points, "outline_color": _CLEAR, "outline_colors": colours,
                "fill_color": _CLEAR, "thickness": 3.0}  # fmt: skip
        return {"circles": rings, "points": [dots] if points else [], "texts": []}

    def _put_paths(self, stamp_ns: int, most: int | None) -> None:
        """The estimated and true trajectories so far as ``nav_msgs/Path``, thinned to at most ``most`` poses
        (None: all), so that publishing them at every keyframe keeps a long log linear in its length."""
        for topic, poses in self._paths.items():
            if not poses:
                continue
            self._put(topic, {"header": _header(stamp_ns, WORLD_FRAME), "poses": [
                {"header": _header(t, WORLD_FRAME), "pose": _pose(T)} for t, T in _thinned(poses, most)]},
                stamp_ns)  # fmt: skip

    def _put_keyframes(self, stamp_ns: int, most: int | None) -> None:
        """The keyframes' estimated poses so far as ``geometry_msgs/PoseArray``, thinned like the paths."""
        kept = _thinned(self._keyframes, most)
        self._put("/map/keyframes", {"header": _header(stamp_ns, WORLD_FRAME), "poses": [_pose(T) for _, T in kept]},
                  stamp_ns)  # fmt: skip

    def close(self, complete: bool = True) -> None:
        """Finish the file (the whole paths, summary and footer) and, if ``complete``, rename it from
        ``.partial`` to its path; safe to call twice."""
        if self._file.closed:
            return
        with held_signals():  # a second Ctrl-C waits until the file is finished
            last = max((poses[-1][0] for poses in self._paths.values() if poses), default=None)
            if last is not None:
                self._put_paths(last, None)
            if self._keyframes:
                self._put_keyframes(self._keyframes[-1][0], None)
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
            if complete:
                self.partial.replace(self.path)
            self._file.close()  # closing releases the lock

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, kind, error, traceback) -> None:
        """A run that ends normally or is interrupted (Ctrl-C, SIGTERM) becomes ``path``; a run that fails
        stays in ``.partial``, leaving whatever ``path`` held."""
        self.close(complete=kind is None or issubclass(kind, KeyboardInterrupt))


def _thinned(poses: list[tuple[int, np.ndarray]], most: int | None) -> list[tuple[int, np.ndarray]]:
    """At most ``most`` of the (stamp, pose) pairs, evenly spaced and always the latest (None: all)."""
    step = 1 if most is None else max(1, -(-len(poses) // most))
    return poses[::step] + ([] if (len(poses) - 1) % step == 0 else [poses[-1]])


def _point_cloud(stamp_ns: int, points: np.ndarray) -> dict:
    """World points (M, 3) as an unordered ``sensor_msgs/PointCloud2`` of float32 x, y, z (little-endian)."""
    data = np.ascontiguousarray(np.asarray(points, "<f4").reshape(-1, 3))
    fields = [{"name": axis, "offset": 4 * i, "datatype": 7, "count": 1} for i, axis in enumerate("xyz")]
    return {"header": _header(stamp_ns, WORLD_FRAME), "height": 1, "width": len(data), "fields": fields,
            "is_bigendian": False, "point_step": 12, "row_step": 12 * len(data), "data": data.tobytes(),
            "is_dense": True}  # fmt: skip


def _image_message(frame: LogFrame) -> dict:
    """/camera/image: the frame as a PNG ``CompressedImage``."""
    ok, png = cv2.imencode(".png", frame.image)
    if not ok:
        raise InputError("could not encode the frame as PNG")
    return {"header": _header(frame.stamp_ns, CAMERA_FRAME), "format": "png", "data": png.tobytes()}


def _camera_info_message(frame: LogFrame) -> dict:
    """/camera/camera_info: the pinhole K the pipeline used (images are already undistorted)."""
    h, w = frame.image.shape
    K = np.asarray(frame.K, np.float64)
    P = np.hstack([K, np.zeros((3, 1))])
    return {
        "header": _header(frame.stamp_ns, CAMERA_FRAME),
        "height": h,
        "width": w,
        "distortion_model": "plumb_bob",
        "d": [0.0] * 5,
        "k": K.ravel().tolist(),
        "r": np.eye(3).ravel().tolist(),
        "p": P.ravel().tolist(),
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


def _covariance_message(frame: LogFrame) -> dict:
    """/estimate/pose_covariance: the estimate with its covariance in ROS's order and axes."""
    pose = {"pose": _pose(frame.T_estimate), "covariance": ros_covariance(frame.covariance, frame.T_estimate)}
    return {"header": _header(frame.stamp_ns, WORLD_FRAME), "pose": pose}


def _transforms(frame: LogFrame) -> list[dict]:
    """/tf: the true camera, then the estimated one, where the frame has them."""
    poses = ((GROUNDTRUTH_FRAME, frame.T_groundtruth), (CAMERA_FRAME, frame.T_estimate))
    return [
        {"header": _header(frame.stamp_ns, WORLD_FRAME), "child_frame_id": child, "transform": _transform(T)}
        for child, T in poses
        if T is not None
    ]


def _tracks_message(frame: LogFrame) -> dict:
    """/frontend/tracks: x, y, score and id of every tracked point."""
    tracks = np.asarray(frame.tracks, np.float64).reshape(-1, 4)
    return {
        "header": _header(frame.stamp_ns, CAMERA_FRAME),
        "x": tracks[:, 0].astype(np.float32).tolist(),
        "y": tracks[:, 1].astype(np.float32).tolist(),
        "score": tracks[:, 2].astype(np.float32).tolist(),
        "id": tracks[:, 3].astype(np.int64).tolist(),
    }


def _correspondences_message(frame: LogFrame) -> dict:
    """/frontend/correspondences: the pairs the frame's pose was measured from, and that pose."""
    c = frame.correspondences
    return {
        "header": _header(frame.stamp_ns, CAMERA_FRAME),
        "reference_stamp": _time(c.reference_stamp_ns),
        "reference_index": np.asarray(c.reference_index, np.uint32).tolist(),
        "current_index": np.asarray(c.current_index, np.uint32).tolist(),
        "model": c.model,
        "inliers": int(c.inliers),
        "t_ref_cur": np.asarray(c.T_ref_cur, np.float64).ravel().tolist(),
    }


def _diagnostics_message(frame: LogFrame) -> dict:
    """/diagnostics/frame: the frame's tracking figures."""
    d = frame.diagnostics
    return {"header": _header(frame.stamp_ns, CAMERA_FRAME), "tracks": int(d.tracks), "inliers": int(d.inliers),
            "lost": bool(d.lost), "reason": d.reason, "correspondence_error_px": float(d.correspondence_error_px),
            "position_error_m": float(d.position_error_m), "keyframe": bool(d.keyframe),
            "pair_error_px": float(d.pair_error_px), "landmarks": int(d.landmarks), "phase": d.phase,
            "keyframe_reason": d.keyframe_reason}  # fmt: skip
