"""Raw access to MCAP records: the reader's fast path, without per-record Python objects.

The mcap library turns every record into a Python object through many small
reads; for a learner reading a 200-step episode that overhead (the summary, the
metadata, per-message records) is larger than the data itself. Here the
summary section is read with one read and walked with ``struct``, a chunk is read
with one seek and decompressed in one call, and its message records are walked to
find payload offsets. Record layouts are those of the MCAP spec (little endian):
a record is opcode u8, length u64, body; strings are u32 length + UTF-8; maps are
u32 byte length + entries. Anything unexpected raises ``ValueError``; the mcap
library's own reader (used by verify and the generic path) stays the reference.

``ChunkWriter`` writes files whose caller closes each chunk with its own compression.
"""

from __future__ import annotations

import os
import struct
import threading
import zlib
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_MESSAGE_INDEX = 0x07
OP_CHUNK_INDEX = 0x08
OP_METADATA = 0x0C
OP_METADATA_INDEX = 0x0D
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_U64 = struct.Struct("<Q")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
MESSAGE_HEAD_SIZE = _MESSAGE_HEAD.size
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length


class CutOffError(ValueError):
    """The file has no valid footer: its writer never finished it."""


@dataclass
class ChunkInfo:
    chunk_start_offset: int
    chunk_length: int
    channel_ids: frozenset
    message_index_offsets: dict = field(default_factory=dict)  # channel id -> MessageIndex offset
    message_index_length: int = 0  # bytes of the MessageIndex records after the chunk


@dataclass
class ChannelInfo:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict


@dataclass
class SchemaInfo:
    id: int
    name: str
    encoding: str


@dataclass
class RawSummary:
    file_size: int = 0
    data_end: int = 0  # where the summary section starts: every chunk and index lies before it
    schemas: dict = field(default_factory=dict)  # id -> SchemaInfo
    channels: dict = field(default_factory=dict)  # id -> ChannelInfo
    chunks: list = field(default_factory=list)  # ChunkInfo in file order
    metadata_offsets: dict = field(default_factory=dict)  # name -> [(offset, length)]


class _Cursor:
    def __init__(self, data, pos: int = 0):
        self.data, self.pos = data, pos

    def u16(self) -> int:
        (v,) = struct.unpack_from("<H", self.data, self.pos)
        self.pos += 2
        return v

    def u32(self) -> int:
        (v,) = struct.unpack_from("<I", self.data, self.pos)
        self.pos += 4
        return v

    def u64(self) -> int:
        (v,) = _U64.unpack_from(self.data, self.pos)
        self.pos += 8
        return v

    def string(self) -> str:
        n = self.u32()
        v = bytes(self.data[self.pos:self.pos + n]).decode()
        self.pos += n
        return v

    def string_map(self) -> dict:
        end = self.u32() + self.pos
        out = {}
        while self.pos < end:
            key = self.string()
            out[key] = self.string()
        return out


def read_summary(stream, validate_crc: bool = True) -> RawSummary:
    """Schemas, channels, chunk indexes and metadata offsets of a finished MCAP file.

    Raises ``ValueError`` if the file does not start with the MCAP magic, if (``validate_crc``)
    the summary section fails the footer's CRC, or if an index points outside the data
    section; ``CutOffError`` if it does not end with a footer and the magic (cut off).
    """
    stream.seek(0)
    if stream.read(8) != MAGIC:
        raise ValueError("does not start with the MCAP magic bytes")
    size = stream.seek(0, 2)
    if size < 8 + _FOOTER_SIZE + 8:
        raise CutOffError("too short to hold an MCAP footer")
    stream.seek(size - _FOOTER_SIZE - 8)
    tail = stream.read(_FOOTER_SIZE + 8)
    if tail[-8:] != MAGIC or tail[0] != OP_FOOTER:
        raise CutOffError("does not end with an MCAP footer")
    summary_start, summary_offset_start, summary_crc = struct.unpack_from("<QQI", tail, 9)
    if summary_start == 0:
        raise CutOffError("has no summary section")
    if not 8 <= summary_start <= size - _FOOTER_SIZE - 8:
        raise ValueError(f"its footer points the summary at offset {summary_start}, outside the file")
    stream.seek(summary_start)
    data = stream.read(size - _FOOTER_SIZE - 8 - summary_start)
    if validate_crc and summary_crc:
        footer_head = struct.pack("<BQQQ", OP_FOOTER, 8 + 8 + 4, summary_start, summary_offset_start)
        if zlib.crc32(footer_head, zlib.crc32(data)) != summary_crc:
            raise ValueError("its summary section fails the footer's CRC check")
    summary = RawSummary(file_size=size, data_end=summary_start)
    pos = 0
    while pos < len(data):
        opcode = data[pos]
        (length,) = _U64.unpack_from(data, pos + 1)
        body = _Cursor(data, pos + 9)
        if opcode == OP_SCHEMA:
            schema = SchemaInfo(body.u16(), body.string(), body.string())
            summary.schemas[schema.id] = schema
        elif opcode == OP_CHANNEL:
            channel = ChannelInfo(body.u16(), body.u16(), body.string(), body.string(), body.string_map())
            summary.channels[channel.id] = channel
        elif opcode == OP_CHUNK_INDEX:
            body.pos += 16  # message start / end time
            start, length_ = body.u64(), body.u64()
            end = body.u32() + body.pos
            offsets = {}
            while body.pos < end:
                channel_id = body.u16()
                offsets[channel_id] = body.u64()
            summary.chunks.append(ChunkInfo(start, length_, frozenset(offsets), offsets, body.u64()))
        elif opcode == OP_METADATA_INDEX:
            offset, length_ = body.u64(), body.u64()
            summary.metadata_offsets.setdefault(body.string(), []).append((offset, length_))
        pos += 9 + length
    summary.chunks.sort(key=lambda c: c.chunk_start_offset)
    for chunk in summary.chunks:  # a hostile length must not make a reader allocate gigabytes
        if chunk.chunk_start_offset + chunk.chunk_length + chunk.message_index_length > summary.data_end:
            raise ValueError(f"a chunk index points at {chunk.chunk_start_offset} + {chunk.chunk_length} bytes, "
                             f"past the data section's end at {summary.data_end}")
    for places in summary.metadata_offsets.values():
        for offset, length in places:
            if offset + length > summary.data_end:
                raise ValueError(f"a metadata index points at {offset} + {length} bytes, past the data section")
    return summary


def read_metadata_record(stream, offset: int, length: int) -> tuple[str, dict]:
    """(name, {key: value}) of the Metadata record at ``offset``."""
    stream.seek(offset)
    data = stream.read(length)
    if len(data) != length or data[0] != OP_METADATA:
        raise ValueError(f"no metadata record at offset {offset}")
    body = _Cursor(data, 9)
    return body.string(), body.string_map()


def read_chunk_records(stream, chunk_index, validate_crc: bool = False) -> bytes:
    """The decompressed records of the chunk that ``chunk_index`` (a ChunkInfo) points at."""
    raw, _, buffer = _read_chunk(stream, chunk_index)
    try:
        return bytes(_decompress(*raw, validate_crc=validate_crc))
    finally:
        _BUFFERS.give(buffer)


def iter_chunk_records(stream, chunk_indexes, validate_crc: bool = False) -> Iterator:
    """The decompressed records of several chunks, in order (see ``ChunkBatch``)."""
    with ChunkBatch(stream, chunk_indexes, validate_crc=validate_crc) as batch:
        yield from batch


class ChunkBatch:
    """Several chunks of one file, read at once and decompressed in parallel.

    The chunks' bytes are read in this thread; when more than one chunk is compressed,
    all but the first are decompressed by a shared thread pool (``READ_THREADS``
    workers; zstd and lz4 release the GIL) while this thread decompresses the first
    and the caller works on what is yielded, so one episode's clouds decode on
    several cores. Chunks are read, and zstd chunks decompressed, into reused buffers
    (on a VM a fresh large allocation costs a page fault per 4 KiB, which rivals
    the decompression): iterating yields each chunk's records, valid until the batch
    is closed (use it as a context manager); copy what you keep.

    ``index_of`` (a channel id): ``indexes`` holds that channel's MessageIndex of each
    chunk as a numpy array of (log_time, offset) pairs (read in the same read as the
    chunk), or None for a chunk without one; available before iterating.
    """

    def __init__(self, stream, chunk_indexes, validate_crc: bool = False, index_of: int | None = None):
        self._raws, self.indexes, self._taken, self._futures = [], [], [], []
        self._validate_crc = validate_crc
        try:
            for chunk_index in chunk_indexes:
                raw, index, buffer = _read_chunk(stream, chunk_index, index_of)
                self._raws.append(raw)
                self.indexes.append(index)
                self._taken.append(buffer)
        except Exception:
            self.close()
            raise
        self._outputs = [_BUFFERS.take(r[2]) if r[1] == "zstd" else None for r in self._raws]
        self._taken.extend(o for o in self._outputs if o is not None)

    def __iter__(self) -> Iterator:
        raws, outputs = self._raws, self._outputs
        self._futures = [None] * len(raws)
        pool = _pool() if sum(1 for r in raws if r[1]) > 1 else None
        if pool is not None:
            self._futures[1:] = [pool.submit(_decompress, *raw, validate_crc=self._validate_crc, into=out)
                                 for raw, out in zip(raws[1:], outputs[1:])]
        for raw, out, future in zip(raws, outputs, self._futures):
            yield (_decompress(*raw, validate_crc=self._validate_crc, into=out) if future is None
                   else future.result())

    def __enter__(self) -> "ChunkBatch":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for future in self._futures:
            if future is not None and not future.cancel():
                try:
                    future.result()  # a running worker finishes before its buffer is reused
                except Exception:  # noqa: BLE001 - raised to the caller already, or not wanted
                    pass
        self._futures = []
        for buffer in self._taken:
            _BUFFERS.give(buffer)
        self._taken = []


class _BufferPool:
    """Reusable bytearrays for chunk bytes, shared by threads (list.pop/append are atomic)."""

    def __init__(self, keep: int = 16):
        self._free: list[bytearray] = []
        self._keep = keep

    def take(self, size: int) -> bytearray:
        held = []
        try:
            while True:
                buffer = self._free.pop()
                if len(buffer) >= size:
                    return buffer
                held.append(buffer)
        except IndexError:
            return bytearray(max(size, 64 << 10) * 5 // 4)
        finally:
            self._free.extend(held)

    def give(self, buffer: bytearray) -> None:
        if len(self._free) < self._keep:
            self._free.append(buffer)


_BUFFERS = _BufferPool()
MESSAGE_INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])


def _read_chunk(stream, chunk_index, index_of: int | None = None) -> tuple:
    """((records view, compression, uncompressed size, crc, offset), MessageIndex array or None,
    the pooled buffer holding the bytes)."""
    stream.seek(chunk_index.chunk_start_offset)
    index_offset = chunk_index.message_index_offsets.get(index_of) if index_of is not None else None
    size = chunk_index.chunk_length + (chunk_index.message_index_length if index_offset is not None else 0)
    buffer = _BUFFERS.take(size)
    raw = memoryview(buffer)[:size]
    try:
        if stream.readinto(raw) != size or raw[0] != OP_CHUNK:
            raise ValueError(f"no chunk at offset {chunk_index.chunk_start_offset}")
        index = None
        if index_offset is not None:
            pos = index_offset - chunk_index.chunk_start_offset
            if raw[pos] != OP_MESSAGE_INDEX:
                raise ValueError(f"no message index at offset {index_offset}")
            (records_len,) = struct.unpack_from("<I", raw, pos + 9 + 2)
            index = np.frombuffer(raw, MESSAGE_INDEX_ENTRY, records_len // 16, pos + 9 + 2 + 4).copy()
        pos = 9
        _, _, uncompressed_size, crc, comp_len = _CHUNK_HEAD.unpack_from(raw, pos)
        pos += _CHUNK_HEAD.size
        compression = bytes(raw[pos:pos + comp_len]).decode()
        pos += comp_len
        (records_len,) = _U64.unpack_from(raw, pos)
        pos += 8
        _check_sizes(raw[pos:pos + records_len], records_len, compression, uncompressed_size,
                     chunk_index.chunk_start_offset)
    except Exception:
        _BUFFERS.give(buffer)
        raise
    records = raw[pos:pos + records_len]
    return (records, compression, uncompressed_size, crc, chunk_index.chunk_start_offset), index, buffer


MAX_CHUNK_BYTES = 256 << 20  # episode chunks hold a few MB; a larger claim is a corrupt length field


def _check_sizes(records, records_len: int, compression: str, uncompressed_size: int, offset: int) -> None:
    """The chunk's lengths agree with each other and with its data, before anything is allocated."""
    if len(records) != records_len:
        raise ValueError(f"chunk at offset {offset} claims {records_len} bytes of records, holds {len(records)}")
    if uncompressed_size > MAX_CHUNK_BYTES:
        raise ValueError(f"chunk at offset {offset} claims {uncompressed_size} uncompressed bytes")
    if compression == "" and uncompressed_size != records_len:
        raise ValueError(f"uncompressed chunk at offset {offset} claims {uncompressed_size} bytes, holds {records_len}")
    if compression == "zstd":
        try:
            declared = zstandard.frame_content_size(records)
        except zstandard.ZstdError as exc:
            raise ValueError(f"chunk at offset {offset} is not a zstd frame ({exc})") from exc
        if declared >= 0 and declared != uncompressed_size:
            raise ValueError(f"chunk at offset {offset} claims {uncompressed_size} uncompressed bytes, "
                             f"its zstd frame {declared}")


def _decompress(records, compression: str, uncompressed_size: int, crc: int, offset: int,
                validate_crc: bool = False, into: bytearray | None = None):
    """The chunk's records (bytes or a memoryview); zstd data goes into ``into`` if given."""
    if compression == "zstd" and into is not None:
        data = memoryview(into)[:uncompressed_size]
        reader = _zstd_decompressor().stream_reader(records)
        done = 0
        while done < uncompressed_size:
            n = reader.readinto(data[done:])
            if not n:
                raise ValueError(f"chunk at offset {offset} decompresses to {done} bytes, "
                                 f"not {uncompressed_size}")
            done += n
    elif compression == "zstd":
        data = _zstd_decompressor().decompress(records, max_output_size=uncompressed_size)
    elif compression == "lz4":
        info = lz4.frame.get_frame_info(records)
        if info.get("content_size") not in (0, None, uncompressed_size):
            raise ValueError(f"chunk at offset {offset} claims {uncompressed_size} uncompressed bytes, "
                             f"its lz4 frame {info['content_size']}")
        data = lz4.frame.decompress(records)
        if len(data) != uncompressed_size:
            raise ValueError(f"chunk at offset {offset} decompresses to {len(data)} bytes, not {uncompressed_size}")
    elif compression == "":
        data = records  # a view of the bytes read: no copy
    else:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    if validate_crc and crc and zlib.crc32(data) != crc:
        raise ValueError(f"chunk at offset {offset} fails its CRC check")
    return data


# Threads that decompress a file's chunks in parallel: HINGELAB_READ_THREADS, else the
# machine's cores (at most 8); 1 turns the pool off.
READ_THREADS = int(os.environ.get("HINGELAB_READ_THREADS", 0)) or min(8, os.cpu_count() or 1)
_local = threading.local()
_pool_state: dict = {}


def _zstd_decompressor():
    """One decompressor per thread (a ZstdDecompressor must not be shared across threads)."""
    decompressor = getattr(_local, "zstd", None)
    if decompressor is None:
        decompressor = _local.zstd = zstandard.ZstdDecompressor()
    return decompressor


def _pool():
    if READ_THREADS <= 1:
        return None
    if _pool_state.get("pid") != os.getpid():  # none yet, or inherited through fork (threads gone)
        _pool_state.update(pid=os.getpid(), pool=ThreadPoolExecutor(READ_THREADS, "hingelab-read"))
    return _pool_state["pool"]


def message_spans(records: bytes, channel_id: int | None = None) -> list[tuple[int, int, int]]:
    """(log_time_ns, payload_start, payload_end) of each message (of one channel) in a chunk."""
    spans = []
    pos, end = 0, len(records)
    unpack_u64, unpack_head = _U64.unpack_from, _MESSAGE_HEAD.unpack_from
    while pos < end:
        opcode = records[pos]
        (length,) = unpack_u64(records, pos + 1)
        body = pos + 9
        if opcode == OP_MESSAGE:
            channel, _, log_time, _ = unpack_head(records, body)
            if channel_id is None or channel == channel_id:
                spans.append((log_time, body + _MESSAGE_HEAD.size, body + length))
        pos = body + length
    return spans


# --- writing: chunks with a compression chosen per chunk ---------------------------------------
COMPRESSIONS = ("zstd", "lz4", "none")  # "none" is the empty compression string in the file


class ChunkWriter:
    """A minimal MCAP writer whose caller closes chunks and picks each chunk's compression.

    MCAP stores the compression per Chunk record (and per ChunkIndex), and standard
    readers (``mcap``, Foxglove, Rerun) decompress each chunk by its own field, so a
    file may mix zstd, lz4 and uncompressed chunks. The mcap library's ``Writer`` uses
    one compression for every chunk; this writer serializes every record except the
    messages with the library's own record classes (``mcap.records``), writes message
    records with ``struct`` (the spec's layout: opcode, length, channel u16, sequence
    u32, log time u64, publish time u64, payload), and writes the same summary
    section as the library's ``Writer`` (schemas, channels, statistics, chunk and
    metadata indexes, summary offsets, CRCs). Schema and channel records go into the
    next chunk written (as the library does), so a cut-off file keeps them with the
    first messages that need them.
    """

    def __init__(self, stream, library: str = "hingelab", zstd_level: int = 3):
        self._stream = stream
        self._library = library
        self._records = RecordBuilder()  # top-level records waiting to be written
        self._zstd = zstandard.ZstdCompressor(level=zstd_level)
        self._schemas: dict = {}  # id -> mcap.records.Schema
        self._channels: dict = {}  # id -> mcap.records.Channel
        self._unwritten: list = []  # schema / channel records not yet in a chunk
        self._chunk_indexes: list = []
        self._metadata_indexes: list = []
        self._message_counts: dict[int, int] = {}
        self._message_count = 0
        self._start_time: int | None = None
        self._end_time = 0
        self._metadata_count = 0

    # the subset of mcap.writer.Writer's interface that EpisodeWriter and mcap_protobuf use
    def start(self, profile: str = "", library: str | None = None) -> None:
        self._stream.write(MAGIC)
        Header(profile, library or self._library).write(self._records)
        self._write_records()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas[schema.id] = schema
        self._unwritten.append(schema)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata=None) -> int:
        channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata=dict(metadata or {}))
        self._channels[channel.id] = channel
        self._unwritten.append(channel)
        return channel.id

    def add_metadata(self, name: str, data: dict) -> None:
        offset = self._stream.tell()
        Metadata(name=name, metadata=data).write(self._records)
        length = self._records.count
        self._write_records()
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._metadata_count += 1

    def write_chunk(self, messages, compression: str = "zstd") -> None:
        """One Chunk record holding ``messages`` ((channel_id, log_time, payload, publish_time,
        sequence) tuples, in the order given) and its MessageIndex records."""
        if not messages:
            return
        if compression not in COMPRESSIONS:
            raise ValueError(f"chunk compression must be one of {COMPRESSIONS}, not {compression!r}")
        head = RecordBuilder()
        for record in self._unwritten:
            record.write(head)
        self._unwritten = []
        parts = [head.end()]
        pos = len(parts[0])
        indexes: dict[int, list] = {}
        pack_head = _RECORD_MESSAGE_HEAD.pack
        for channel_id, log_time, payload, publish_time, sequence in messages:
            indexes.setdefault(channel_id, []).append((log_time, pos))
            parts.append(pack_head(OP_MESSAGE, 22 + len(payload), channel_id, sequence, log_time, publish_time))
            parts.append(payload)
            pos += 31 + len(payload)
            self._message_counts[channel_id] = self._message_counts.get(channel_id, 0) + 1
        data = b"".join(parts)
        times = [m[1] for m in messages]
        start, end = min(times), max(times)
        self._message_count += len(messages)
        self._start_time = start if self._start_time is None else min(self._start_time, start)
        self._end_time = max(self._end_time, end)
        if compression == "zstd":
            stored, name = self._zstd.compress(data), "zstd"
        elif compression == "lz4":
            stored, name = lz4.frame.compress(data), "lz4"
        else:
            stored, name = data, ""
        chunk_start = self._stream.tell()
        Chunk(compression=name, data=stored, message_start_time=start, message_end_time=end,
              uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data)).write(self._records)
        chunk_length = self._records.count
        offsets = {}
        for channel_id, records in indexes.items():
            offsets[channel_id] = chunk_start + self._records.count
            MessageIndex(channel_id=channel_id, records=records).write(self._records)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_start,
            chunk_length=chunk_length, message_index_offsets=offsets,
            message_index_length=self._records.count - chunk_length, compression=name,
            compressed_size=len(stored), uncompressed_size=len(data)))
        self._write_records()

    def flush(self) -> None:
        self._write_records()
        self._stream.flush()

    def finish(self) -> None:
        """DataEnd, the summary section (as mcap's Writer writes it), the footer and the magic."""
        DataEnd(0).write(self._records)
        self._write_records()
        summary_start = self._stream.tell()
        summary = RecordBuilder()
        offsets = []

        def group(opcode, records):
            begin = summary.count
            for record in records:
                record.write(summary)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + begin,
                                         group_length=summary.count - begin))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [Statistics(
            attachment_count=0, channel_count=len(self._channels),
            channel_message_counts=dict(self._message_counts), chunk_count=len(self._chunk_indexes),
            message_count=self._message_count, message_end_time=self._end_time,
            message_start_time=self._start_time or 0, metadata_count=self._metadata_count,
            schema_count=len(self._schemas))])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data = summary.end()
        crc = zlib.crc32(struct.pack("<BQQQ", OP_FOOTER, 8 + 8 + 4, summary_start, summary_offset_start),
                         zlib.crc32(data))
        self._stream.write(data)
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
               summary_crc=crc).write(self._records)
        self._write_records()
        self._stream.write(MAGIC)

    def _write_records(self) -> None:
        self._stream.write(self._records.end())


_RECORD_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log/publish time


def record_ends(records, offsets: np.ndarray) -> np.ndarray:
    """End offsets of the records starting at ``offsets`` (numpy, from their u64 length fields)."""
    buffer = np.frombuffer(records, dtype=np.uint8)
    offsets = np.asarray(offsets, dtype=np.int64)
    if len(offsets) and (offsets.min() < 0 or offsets.max() + 9 > len(buffer)):
        raise ValueError("message index points outside its chunk")
    length_bytes = buffer[(offsets + 1)[:, None] + np.arange(8)]
    return offsets + 9 + length_bytes.view("<u8")[:, 0].astype(np.int64)


def all_preceded_by(records, positions: np.ndarray, prefix: bytes) -> bool:
    """Whether ``prefix`` ends exactly at every position (vectorized check of the cloud layout)."""
    buffer = np.frombuffer(records, dtype=np.uint8)
    positions = np.asarray(positions, dtype=np.int64)
    if len(positions) == 0:
        return True
    first = positions - len(prefix)
    if first.min() < 0 or positions.max() > len(buffer):
        return False
    found = buffer[first[:, None] + np.arange(len(prefix))]
    return bool(np.all(found == np.frombuffer(prefix, dtype=np.uint8)))
