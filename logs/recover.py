"""Recovering a killed (``OUT.partial``) or damaged log: every whole frame, copied byte for byte into a
finished MCAP file (summary and footer), which evo and other seeking readers open."""

from __future__ import annotations

from pathlib import Path

from mcap.records import Metadata
from mcap.writer import CompressionType, Writer

from deepslam.files import written
from deepslam.logs.reader import Damage, LogError, frame_messages, raw_records


def recover(log: str | Path, out: str | Path) -> tuple[int, Damage]:
    """Write the whole frames of ``log`` (and its metadata) to ``out``; returns (frames written, what
    was lost). ``out`` is written as ``out.partial`` and renamed when done; never over ``log``, and never
    as an empty log: with no whole frame to recover it is a ``LogError`` and ``out`` keeps what it held."""
    log, out = Path(log), Path(out)
    damage, frames = Damage(), 0
    schemas: dict[int, int] = {}  # schema id in the log -> in the output
    channels: dict[int, int] = {}
    with written(out, inputs=(log,)) as partial, open(partial, "wb") as stream:
        writer = Writer(stream, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="deepslam recover")
        for item in raw_records(log, Damage()):
            if isinstance(item, Metadata):
                writer.add_metadata(item.name, item.metadata)
        for messages in frame_messages(log, damage):
            for raw in messages:
                schema = raw.schema
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                if raw.channel.id not in channels:
                    channels[raw.channel.id] = writer.register_channel(
                        raw.channel.topic,
                        raw.channel.message_encoding,
                        schemas.get(raw.channel.schema_id, 0),
                        raw.channel.metadata,
                    )
                message = raw.message
                writer.add_message(
                    channels[raw.channel.id], message.log_time, message.data, message.publish_time, message.sequence
                )
            frames += 1
        if not frames:
            raise LogError(f"{log}: no whole frame to recover ({damage.report(log, 0)}); {out} left as it was")
        writer.finish()
    return frames, damage
