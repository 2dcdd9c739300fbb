"""Reading runs back from MCAP as typed ``LogFrame``s, including interrupted (truncated) files."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
from mcap.reader import NonSeekingReader
from mcap_ros2.decoder import DecoderFactory

from deepslam.logs.frames import Correspondences, LogFrame, pose_matrix
from deepslam.logs.schemas import FRAME_TOPICS, TOPICS

MAGIC = b"\x89MCAP0\r\n"


class LogError(ValueError):
    """A file that is not an MCAP log, or not one this project can replay."""


def check_log(path: str | Path) -> None:
    """Raise ``LogError`` unless ``path`` is an existing MCAP file (checked by its magic bytes)."""
    path = Path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file")
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise LogError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


def _stamp(time) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def _pose(message) -> np.ndarray:
    p, q = message.position, message.orientation
    return pose_matrix(np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]))


def _apply(frame: dict, topic: str, message) -> None:
    """Store one decoded message into the frame being assembled."""
    if topic == "/camera/image":
        frame["image"] = cv2.imdecode(np.frombuffer(bytes(message.data), np.uint8), cv2.IMREAD_GRAYSCALE)
    elif topic == "/camera/camera_info":
        frame["K"] = np.array(message.k, np.float64).reshape(3, 3)
    elif topic == "/groundtruth/pose":
        frame["T_groundtruth"] = _pose(message.pose)
    elif topic == "/estimate/pose":
        frame["T_estimate"] = _pose(message.pose)
    elif topic == "/frontend/tracks":
        frame["tracks"] = np.stack(
            [
                np.asarray(message.x, np.float64),
                np.asarray(message.y, np.float64),
                np.asarray(message.score, np.float64),
                np.asarray(message.id, np.float64),
            ],
            1,
        )
    elif topic == "/frontend/correspondences":
        frame["correspondences"] = Correspondences(
            _stamp(message.reference_stamp),
            np.asarray(message.reference_index, np.int64),
            np.asarray(message.current_index, np.int64),
            message.model,
            int(message.inliers),
            np.asarray(message.t_ref_cur, np.float64).reshape(4, 4),
        )


def read_frames(path: str | Path) -> Iterator[LogFrame]:
    """Frames of a log in time order. A truncated file (an interrupted run) is read up to its last
    whole chunk, with a warning that says what is missing; a frame missing image or camera info is an
    error."""
    path = Path(path)
    check_log(path)
    parts: dict = {}
    stamp: int | None = None
    count = 0
    topics: set[str] = set()  # the topics of a whole frame (those of the first one)
    topics_now: set[str] = set()  # the topics of the frame being assembled
    with open(path, "rb") as f:
        messages = NonSeekingReader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=list(TOPICS), log_time_order=False
        )
        while True:
            try:
                _, channel, message, decoded = next(messages)
            except StopIteration:
                break
            except Exception as error:  # the mcap library raises several kinds on a cut-off file
                if stamp is not None and topics and topics_now >= topics:  # the pending frame is whole
                    yield _complete(path, stamp, parts)
                    count += 1
                warnings.warn(
                    f"{path} is truncated ({type(error).__name__}: {error}); read {count} whole frames; "
                    f"what came after them, in the file's unfinished last chunk, is missing",
                    stacklevel=2,
                )
                return
            if message.log_time != stamp:
                if stamp is not None:
                    yield _complete(path, stamp, parts)
                    count += 1
                    topics = topics or topics_now
                stamp, parts, topics_now = message.log_time, {}, set()
            _apply(parts, channel.topic, decoded)
            topics_now.add(channel.topic)
    if stamp is None:
        raise LogError(f"{path}: the log lacks the topics {', '.join(FRAME_TOPICS)}; is this a deepslam log?")
    yield _complete(path, stamp, parts)


def _complete(path: Path, stamp: int, parts: dict) -> LogFrame:
    missing = [t for t, key in zip(FRAME_TOPICS, ("image", "K"), strict=False) if key not in parts]
    if missing:
        raise LogError(
            f"{path}: the frame at {stamp} ns lacks the topics {', '.join(missing)}; is this a deepslam log?"
        )
    return LogFrame(
        stamp,
        parts["image"],
        parts["K"],
        parts.get("T_groundtruth"),
        parts.get("T_estimate"),
        None,
        parts.get("tracks"),
        parts.get("correspondences"),
    )


def read_metadata(path: str | Path) -> dict:
    """The run's metadata (configuration, seed, software version), JSON values decoded."""
    path = Path(path)
    check_log(path)
    with open(path, "rb") as f:
        try:
            for record in NonSeekingReader(f).iter_metadata():
                if record.name == "deepslam":
                    return {k: _maybe_json(v) for k, v in record.metadata.items()}
        except Exception as error:
            raise LogError(f"{path}: could not read its metadata ({error})") from error
    raise LogError(f"{path}: no deepslam metadata; was it written by `deepslam run`?")


def _maybe_json(value: str):
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value
