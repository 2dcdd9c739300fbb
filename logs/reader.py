"""Reading runs back from MCAP as typed ``LogFrame``s, checking every chunk on the way.

Chunks are read one at a time: a chunk whose CRC does not match, that does not decompress, that
declares more than ``MAX_CHUNK_BYTES`` uncompressed or decompresses to another size than it declares
(decompression stops one byte past it) is skipped; reading stops where the chunks declare more than
``MAX_TOTAL_BYTES`` in all; and a file that ends inside a chunk (a
run that was killed) is read up to there. Frames touched by a lost part are dropped whole: a frame is
never returned with parts silently missing. What was lost is named, with where it was, in one warning.
"""

from __future__ import annotations

import io
import json
import struct
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, DataEnd, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_ros2.decoder import DecoderFactory

from deepslam.errors import InputError
from deepslam.geometry import pose_matrix
from deepslam.logs.frames import Correspondences, FrameDiagnostics, LogFrame
from deepslam.logs.images import MAX_PIXELS, encoded_size, too_large
from deepslam.logs.schemas import FRAME_TOPICS, METADATA_CHECKSUM, metadata_checksum

MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK_BYTES = 64 * 2**20  # a chunk declaring more than this uncompressed is refused (the writer's are 256 KiB)
MAX_TOTAL_BYTES = 16 * 2**30  # a file whose chunks declare more than this in all is read up to there
MAX_RECORD_BYTES = 256 * 2**20  # a record declaring more than this ends the readable part of the file
FIRST_TOPIC = FRAME_TOPICS[0]  # the writer starts every frame with its image


class LogError(InputError):
    """A file that is not an MCAP log, or not one this project can replay."""


def check_log(path: str | Path) -> None:
    """Raise ``LogError`` unless ``path`` is an existing MCAP file (checked by its magic bytes)."""
    path = Path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file")
    if path.is_dir():
        raise LogError(f"{path}: is a folder, not an MCAP file")
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise LogError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


@dataclass
class Damage:
    """What a read lost: one line per damaged or missing part of the file."""

    problems: list[str] = field(default_factory=list)
    dropped_frames: int = 0
    complete: bool = True  # the file reached its data end

    def report(self, path: Path, frames: int) -> str:
        lost = f"; {_count(self.dropped_frames, 'damaged frame')} dropped" if self.dropped_frames else ""
        return f"{path}: {'; '.join(self.problems)}; read {_count(frames, 'whole frame')}{lost}"


def _count(number: int, noun: str) -> str:
    """A count with its noun, plural but for one: "1 frame", "2 frames"."""
    return f"{number} {noun}{'' if number == 1 else 's'}"


@dataclass
class RawMessage:
    """A message as stored: its channel, that channel's schema (None without one) and the record."""

    schema: Schema | None
    channel: Channel
    message: Message


def _chunk_where(index: int, chunk: Chunk) -> str:
    return f"chunk {index} (log time {chunk.message_start_time / 1e9:.3f}-{chunk.message_end_time / 1e9:.3f} s)"


def raw_records(path: str | Path, damage: Damage) -> Iterator[RawMessage | Metadata | None]:
    """Every readable message (and metadata record) of the file in order, and None where a part of the
    file was lost (a skipped chunk, or the end of what could be read); ``damage`` names each loss."""
    path = Path(path)
    check_log(path)
    schemas, channels = _summary_definitions(path)
    chunks, orphans, declared = 0, 0, 0
    with open(path, "rb") as f:  # definitions in the data section (CRC-checked) replace the summary's
        records = StreamReader(f, emit_chunks=True, record_size_limit=MAX_RECORD_BYTES).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except (McapError, EOFError, ValueError, OSError, struct.error) as error:
                damage.complete = False
                cause = "the file ends" if "EndOfFile" in type(error).__name__ else f"unreadable ({error})"
                damage.problems.append(f"truncated: {cause} after chunk {chunks}")
                yield None
                return
            if isinstance(record, DataEnd):
                return
            inner: list = [record]
            if isinstance(record, Chunk):
                chunks += 1
                declared += record.uncompressed_size
                if declared > MAX_TOTAL_BYTES:
                    damage.complete = False
                    damage.problems.append(
                        f"stopped at chunk {chunks}: the chunks declare over {MAX_TOTAL_BYTES / 2**30:.0f} GiB in all"
                    )
                    yield None
                    return
                inner = _open_chunk(record, chunks, damage)
                if inner is None:
                    yield None
                    continue
            for item in inner:
                if isinstance(item, Schema):
                    schemas[item.id] = item
                elif isinstance(item, Channel):
                    channels[item.id] = item
                elif isinstance(item, Message) and item.channel_id not in channels:
                    orphans += 1
                    if orphans == 1:
                        damage.problems.append("messages on a channel defined in a lost part: skipped")
                    yield None
                elif isinstance(item, Message):
                    channel = channels[item.channel_id]
                    yield RawMessage(schemas.get(channel.schema_id), channel, item)
                elif isinstance(item, Metadata):
                    yield item


def _summary_definitions(path: Path) -> tuple[dict[int, Schema], dict[int, Channel]]:
    """The schemas and channels listed in a finished file's summary (empty for a killed file or a
    damaged summary), so that messages after a lost chunk can still be decoded."""
    try:
        with open(path, "rb") as f:
            summary = SeekingReader(f).get_summary()
    except (McapError, struct.error, ValueError, EOFError, OSError):
        return {}, {}
    return (dict(summary.schemas), dict(summary.channels)) if summary else ({}, {})


def _open_chunk(chunk: Chunk, index: int, damage: Damage) -> list | None:
    """The records of a chunk, or None (and the loss named in ``damage``) if it is damaged."""
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        damage.problems.append(
            f"{_chunk_where(index, chunk)} declares {chunk.uncompressed_size / 2**20:.0f} MiB, over the "
            f"{MAX_CHUNK_BYTES / 2**20:.0f} MiB limit: skipped"
        )
        return None
    try:
        data = _decompressed(chunk)
        if len(data) != chunk.uncompressed_size:
            damage.problems.append(
                f"{_chunk_where(index, chunk)} declares {chunk.uncompressed_size} bytes but holds "
                f"{'more' if len(data) > chunk.uncompressed_size else len(data)}: skipped"
            )
            return None
        return breakup_chunk(replace(chunk, compression="", data=data), validate_crc=True)
    except (McapError, zstandard.ZstdError, struct.error, ValueError, RuntimeError, EOFError) as error:
        damage.problems.append(f"{_chunk_where(index, chunk)} is corrupt ({type(error).__name__}): skipped")
        return None


def _decompressed(chunk: Chunk) -> bytes:
    """A chunk's records, decompressed as a stream that stops one byte past what the chunk declares (a
    frame header may promise gigabytes; the decompressor would allocate them), so that a chunk that lies
    about its size costs at most its declared size (``MAX_CHUNK_BYTES``) in memory and time."""
    limit = chunk.uncompressed_size + 1
    if chunk.compression == "":
        return chunk.data[:limit]
    if chunk.compression == "zstd":
        reader = zstandard.ZstdDecompressor(max_window_size=MAX_CHUNK_BYTES).stream_reader(chunk.data)
    elif chunk.compression == "lz4":
        import lz4.frame

        reader = lz4.frame.LZ4FrameFile(io.BytesIO(chunk.data))
    else:
        raise ValueError(f"unknown compression {chunk.compression!r}")
    parts, size = [], 0
    while size < limit:
        part = reader.read(limit - size)
        if not part:
            break
        parts.append(part)
        size += len(part)
    return b"".join(parts)


def frame_messages(path: str | Path, damage: Damage) -> Iterator[list[RawMessage]]:
    """The messages of each whole frame (same log time, starting with the image, nothing lost in
    between), in order; frames touched by a lost part are counted in ``damage`` and not yielded."""
    pending: list[RawMessage] = []
    whole = after_loss = False
    for item in raw_records(path, damage):
        if item is None:  # a lost part: the frame being assembled may lack messages
            damage.dropped_frames += bool(pending)
            pending, whole, after_loss = [], False, True
            continue
        if isinstance(item, Metadata):
            continue
        if pending and item.message.log_time != pending[0].message.log_time:
            if whole:
                yield pending
                after_loss = False
            else:
                damage.dropped_frames += after_loss  # its head was lost (else: not a frame of ours)
            pending = []
        if not pending:
            whole = item.channel.topic == FIRST_TOPIC  # a frame whose head was lost does not start with it
        pending.append(item)
    if pending and whole and damage.complete:
        yield pending
    elif pending and (whole or after_loss):
        damage.dropped_frames += 1


def _stamp(time) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def _pose(message) -> np.ndarray:
    p, q = message.position, message.orientation
    return pose_matrix(np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]))


def _apply(frame: dict, topic: str, message) -> None:
    """Store one decoded message into the frame being assembled."""
    if topic == "/camera/image":
        if too_large(encoded_size(bytes(message.data[:65536]))):
            raise InputError(f"the image is over {MAX_PIXELS} pixels")
        frame["image"] = cv2.imdecode(np.frombuffer(bytes(message.data), np.uint8), cv2.IMREAD_GRAYSCALE)
        if frame["image"] is None:
            raise InputError("the image does not decode")
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
    elif topic == "/diagnostics/frame":
        frame["diagnostics"] = FrameDiagnostics(
            int(message.tracks), int(message.inliers), bool(message.lost), message.reason,
            float(message.correspondence_error_px), float(message.position_error_m), bool(message.keyframe),
            float(getattr(message, "pair_error_px", float("nan"))),  # logs of 0.2.0 lack it
            int(getattr(message, "landmarks", 0)),  # logs before the map lack it
            getattr(message, "phase", ""), getattr(message, "keyframe_reason", ""),  # older logs lack them
        )  # fmt: skip
    elif topic == "/frontend/correspondences":
        frame["correspondences"] = Correspondences(
            _stamp(message.reference_stamp),
            np.asarray(message.reference_index, np.int64),
            np.asarray(message.current_index, np.int64),
            message.model,
            int(message.inliers),
            np.asarray(message.t_ref_cur, np.float64).reshape(4, 4),
        )


class _Decoders:
    """CDR decoders per schema, made once."""

    def __init__(self):
        self.factory, self.by_schema = DecoderFactory(), {}

    def decode(self, raw: RawMessage):
        if raw.schema is None:
            raise LogError(f"topic {raw.channel.topic} has no schema")
        if raw.schema.id not in self.by_schema:
            self.by_schema[raw.schema.id] = self.factory.decoder_for(raw.channel.message_encoding, raw.schema)
        decoder = self.by_schema[raw.schema.id]
        if decoder is None:
            raise LogError(f"topic {raw.channel.topic}: no decoder for {raw.channel.message_encoding}")
        return decoder(raw.message.data)


def read_frames(path: str | Path) -> Iterator[LogFrame]:
    """The frames of a log written by ``deepslam run`` or ``replay``.

    Args:
        path: the MCAP file (a finished log, its ``.partial``, or a damaged one).

    Returns:
        An iterator of whole ``LogFrame``s in time order (image, K, true and estimated pose, covariance,
        tracks, correspondences, diagnostics); what a damaged or cut-off file lost is named in one warning at
        the end. A file without the frame topics (not a deepslam log) is a ``LogError``.
    """
    path = Path(path)
    damage, decoders, count = Damage(), _Decoders(), 0
    for messages in frame_messages(path, damage):
        stamp, parts = messages[0].message.log_time, {}
        try:
            for raw in messages:
                _apply(parts, raw.channel.topic, decoders.decode(raw))
        except Exception as error:  # noqa: BLE001 - the decoders parse damaged bytes: any failure drops the frame
            damage.problems.append(f"the frame at {stamp / 1e9:.3f} s does not decode ({type(error).__name__})")
            damage.dropped_frames += 1
            continue
        yield _complete(path, stamp, parts)
        count += 1
    if not count and (damage.problems or damage.dropped_frames):
        raise LogError(f"no whole frame could be read: {damage.report(path, count)}")
    if not count:
        raise LogError(f"{path}: the log lacks the topics {', '.join(FRAME_TOPICS)}; is this a deepslam log?")
    if damage.problems or damage.dropped_frames:
        warnings.warn(damage.report(path, count), stacklevel=2)


def _complete(path: Path, stamp: int, parts: dict) -> LogFrame:
    missing = [t for t, key in zip(FRAME_TOPICS, ("image", "K"), strict=True) if key not in parts]
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
        parts.get("diagnostics"),
    )


def read_metadata(path: str | Path, record: str = "deepslam") -> dict:
    """The run's metadata (configuration, seed, software version), JSON values decoded, or another of its
    records (``SUMMARY_RECORD``: the figures the run printed); a record that does not match its checksum (logs
    since 2026-12 carry one) is reported in a warning."""
    path = Path(path)
    for item in raw_records(path, Damage()):
        if isinstance(item, Metadata) and item.name == record:
            entries = dict(item.metadata)
            stored = entries.pop(METADATA_CHECKSUM, None)
            if stored is not None and stored != metadata_checksum(entries):
                warnings.warn(
                    f"{path}: the metadata record does not match its checksum: its settings may be wrong", stacklevel=2
                )
            return {k: _maybe_json(v) for k, v in entries.items()}
    raise LogError(f"{path}: no {record} metadata; was it written by `deepslam run` (2026-12 or later)?")


def _maybe_json(value: str):
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value
