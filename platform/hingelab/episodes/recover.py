"""``recover``: salvage every complete message of a cut-off episode into a new, valid file.

A writer killed mid-episode leaves ``<id>.mcap.partial``: the header, the
``episode_start`` record and the chunks it had written, then a cut (possibly in
the middle of a chunk). This reads it linearly, keeps every record of every
complete chunk (CRC checked), then decompresses as much of a cut chunk as the
bytes allow and keeps its complete message records too. The new file has the
same channels and message bytes, rebuilt ``/episode/columns``, and an
``episode`` record with ``recovered=true``, ``success=false``, ``length`` = the
number of salvaged ``/step`` records and a ``failure_reason`` saying so.
"""

from __future__ import annotations

import io
import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from hingelab.episodes import codec
from hingelab.episodes import schemas as S
from hingelab.episodes.card import EPISODES_DIR, load_card
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.metadata import digest_columns, format_metadata, parse_metadata
from hingelab.episodes.reader import stack_messages
from hingelab.episodes.writer import PARTIAL_SUFFIX, column_name

_OPCODES = {0x03: Schema, 0x04: Channel, 0x05: Message}


@dataclass
class Salvage:
    schemas: dict
    channels: dict
    messages: list  # mcap Message records, file order
    metadata: dict  # name -> {key: value}
    cut_at: int | None  # byte offset of the cut, None if the file was complete


def _partial_chunk_records(data: bytes) -> list:
    """Complete Schema/Channel/Message records from the start of a cut Chunk record's bytes."""
    try:
        head = struct.unpack_from("<QQQII", data, 9)
        compression_len = head[4]
        pos = 9 + struct.calcsize("<QQQII")
        compression = data[pos:pos + compression_len].decode()
        pos += compression_len + 8
        body = data[pos:]
    except (struct.error, UnicodeDecodeError):
        return []
    if compression == "zstd":
        try:  # a streaming decompressor returns whatever the truncated frame holds
            inner = zstandard.ZstdDecompressor().decompressobj().decompress(body)
        except zstandard.ZstdError:
            return []
    elif compression == "lz4":
        try:
            inner = lz4.frame.LZ4FrameDecompressor().decompress(body)
        except RuntimeError:
            return []
    else:
        inner = body
    records, pos = [], 0
    while pos + 9 <= len(inner):
        opcode = inner[pos]
        (length,) = struct.unpack_from("<Q", inner, pos + 1)
        if pos + 9 + length > len(inner):
            break  # the record the cut went through
        cls = _OPCODES.get(opcode)
        if cls is not None:
            stream = ReadDataStream(io.BytesIO(inner[pos + 9:pos + 9 + length]))
            records.append(cls.read(stream, length) if cls is Message else cls.read(stream))
        pos += 9 + length
    return records


def salvage(path) -> Salvage:
    """Every complete record of a (possibly cut-off) MCAP file."""
    path = Path(path)
    out = Salvage({}, {}, [], {}, None)
    with open(path, "rb") as stream:
        if stream.read(8) != b"\x89MCAP0\r\n":
            raise DatasetError(f"{path} is not an MCAP file (bad magic bytes); nothing to recover")
        stream.seek(0)
        end_of_good = 8
        records = StreamReader(stream, emit_chunks=True, validate_crcs=True).records
        try:
            for record in records:
                inner = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
                for item in inner:
                    _keep(out, item)
                end_of_good = stream.tell()
        except Exception:  # noqa: BLE001 - the cut (EOF, bad CRC, garbage): keep what came before
            out.cut_at = end_of_good
            stream.seek(end_of_good)
            tail = stream.read()
            if tail[:1] == b"\x06":
                for item in _partial_chunk_records(tail):
                    _keep(out, item)
    return out


def _keep(out: Salvage, record) -> None:
    if isinstance(record, Schema):
        out.schemas[record.id] = record
    elif isinstance(record, Channel):
        out.channels[record.id] = record
    elif isinstance(record, Message):
        if record.channel_id in out.channels:
            out.messages.append(record)
    elif isinstance(record, Metadata):
        out.metadata[record.name] = dict(record.metadata)


def recover_episode(path, out_path) -> dict:
    """Write the salvaged messages of ``path`` to ``out_path`` as a valid, marked episode.

    Returns a summary: messages and steps salvaged, whether the file was cut off.
    """
    path, out_path = Path(path), Path(out_path)
    if out_path.exists():
        raise DatasetError(f"{out_path} exists; choose a new --out file name")
    found = salvage(path)
    topics = {c.id: c.topic for c in found.channels.values()}
    foreign = [c.topic for c in found.channels.values() if c.topic not in S.TOPIC_TYPES]
    if foreign:
        raise DatasetError(f"{path} has topics outside the episode contract ({', '.join(foreign)}); "
                           "it is not a hingelab episode")
    messages = [m for m in found.messages if topics[m.channel_id] != S.TOPIC_COLUMNS]
    decoded = [(topics[m.channel_id], m.log_time, S.TOPIC_TYPES[topics[m.channel_id]].FromString(m.data))
               for m in sorted(messages, key=lambda m: m.log_time)]
    dtypes = {c.topic: _json(c.metadata.get(S.CHANNEL_DTYPES_KEY)) for c in found.channels.values()}
    arrays, final = stack_messages(decoded, dtypes)
    steps = len(arrays.get(S.TOPIC_STEP, {}).get("log_time_ns", []))
    closed = S.METADATA_EPISODE in found.metadata  # the writer got as far as close()
    facts = parse_metadata(found.metadata.get(S.METADATA_EPISODE)
                           or found.metadata.get(S.METADATA_EPISODE_START) or {})
    reward = arrays.get(S.TOPIC_STEP, {}).get("reward")
    last_ns = max((m.log_time for m in messages), default=0)
    origin_ns = int(facts.get(S.KEY_LOG_TIME_ORIGIN, 0) or 0)  # schema 6: log times are wall clock
    facts.update({
        S.KEY_LENGTH: steps, S.KEY_RETURN: float(reward.sum()) if reward is not None else 0.0,
        S.KEY_TRUNCATED_FILE: found.cut_at is not None, S.KEY_END_TIME: max(last_ns - origin_ns, 0) / 1e9,
    })
    if found.cut_at is not None and not closed:
        facts.update({S.KEY_SUCCESS: False,
                      S.KEY_FAILURE_REASON: f"recovered from a file cut off at byte {found.cut_at}: "
                                            f"{steps} complete steps"})
    for key, default in ((S.KEY_SOURCE, "unknown"), (S.KEY_TASK, ""), (S.KEY_OBJECT, ""), (S.KEY_SEED, 0),
                         (S.KEY_ATTEMPT, 1), (S.KEY_CONFIG_HASH, ""), (S.KEY_SUCCESS, False)):
        facts.setdefault(key, default)

    columns = {}
    for topic, fields in arrays.items():
        for name, array in fields.items():
            if topic != S.TOPIC_POINTS or name == "log_time_ns":
                columns[column_name(topic, name)] = array
    for name, value in final.items():
        columns[column_name(S.TOPIC_STEP, "final." + name)] = value[None]

    # hidden (readers and verify skip dot files), and never the .partial being salvaged
    temp = out_path.with_name("." + out_path.name + ".recovering")
    with open(temp, "wb") as stream:
        writer = Writer(stream, chunk_size=1 << 40, compression=CompressionType.ZSTD)
        writer.start(profile="", library="hingelab recover")
        start_record = found.metadata.get(S.METADATA_EPISODE_START, {})
        writer.add_metadata(S.METADATA_EPISODE_START, start_record)
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in found.schemas.items()}
        channel_ids = {}
        for cid, channel in found.channels.items():
            channel_ids[cid] = writer.register_channel(channel.topic, channel.message_encoding,
                                                       schema_ids.get(channel.schema_id, 0), channel.metadata)
        # Same layout as EpisodeWriter: clouds in their own chunk, then the rest, then the columns.
        for is_cloud in (True, False):
            for m in messages:
                if (topics[m.channel_id] == S.TOPIC_POINTS) == is_cloud:
                    writer.add_message(channel_ids[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
            writer.flush()
        if S.TOPIC_COLUMNS not in {c.topic for c in found.channels.values()}:
            columns_channel = writer.register_channel(S.TOPIC_COLUMNS, "protobuf",
                                                      register_schema(writer, S.EpisodeColumns))
        else:
            columns_channel = next(channel_ids[c.id] for c in found.channels.values() if c.topic == S.TOPIC_COLUMNS)
        record = format_metadata(facts)
        columns = {**columns, **digest_columns({S.METADATA_EPISODE_START: start_record, S.METADATA_EPISODE: record})}
        writer.add_message(columns_channel, last_ns, codec.encode_columns(last_ns, steps, columns), last_ns)
        writer.add_metadata(S.METADATA_EPISODE, record)
        writer.finish()
        stream.flush()
        os.fsync(stream.fileno())
    os.rename(temp, out_path)
    return {"messages": len(messages), "steps": steps, "cut_off": found.cut_at is not None,
            "cut_at": found.cut_at, "out": out_path}


def _json(text):
    return json.loads(text) if text else None


def recover_folder(root, discard: bool = False) -> dict:
    """Every ``.partial`` file of a dataset folder salvaged into ``episodes/<id>.mcap`` (then removed), or
    removed (``discard``). A partial that cannot be salvaged is kept and reported.

    Returns {"recovered": [paths written], "discarded": [paths removed], "failed": [(path, reason)]}.
    """
    root = Path(root)
    load_card(root)
    out = {"recovered": [], "discarded": [], "failed": []}
    for partial in sorted((root / EPISODES_DIR).glob("*" + PARTIAL_SUFFIX)):
        if discard:
            partial.unlink()
            out["discarded"].append(partial)
            continue
        target = partial.with_name(partial.name[:-len(PARTIAL_SUFFIX)])
        try:
            recover_episode(partial, target)
        except DatasetError as exc:
            out["failed"].append((partial, str(exc)))
            continue
        partial.unlink()  # only once its salvage is written under the final name
        out["recovered"].append(target)
    return out


__all__ = ["Salvage", "salvage", "recover_episode", "recover_folder"]
