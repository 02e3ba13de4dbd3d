"""Read an episode file into numpy arrays per topic.

``read_episode(path)`` returns an ``Episode``: ``episode.topics[topic][field]`` is a
numpy array with one row per message of that topic (per step), plus
``log_time_ns``. Two ways in:

- fast (files from ``EpisodeWriter``): every field except clouds comes from the one
  ``/episode/columns`` message; clouds are sliced out of cloud-only chunks
  (``mcap_raw.py``: read with their message indexes, decompressed in parallel, any
  per-chunk compression) without decoding a message;
- generic (any file whose messages use the contract's schemas, e.g. written by
  another tool): every message is decoded with protobuf and stacked.
Both give identical arrays (tested). Times are episode times: the file's log times minus its
``log_time_origin_ns`` (schema 6 files log at the episode's wall-clock start; older ones from 0, no origin).

Errors a user can act on (not an MCAP file, cut off, foreign schema, written by a
newer schema version) raise ``DatasetError`` naming the file and the fix.

Reading validates (``validate=True``, the default): the summary section against the footer's
CRC, every chunk read against its CRC, every length field against the file before anything
is allocated, the clouds' positions from the chunk's own records (the MessageIndex after a
chunk is not under its CRC), and the metadata records against the CRC32s the writer stored in
the columns (``schemas.DIGEST_COLUMNS``; files written before it have none). Any failure to
read becomes one ``DatasetError`` naming the file and ``hingelab datasets verify`` /
``recover``; ``validate=False`` skips the CRCs and the digests for trusted speed runs.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from hingelab.bounded_reads import unreadable_reason
from hingelab.episodes import codec, mcap_raw
from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.metadata import metadata_digest, parse_metadata

# Schema versions this reader understands. A newer reader keeps the older ones here and
# maps old topics/fields onto new names when a version renames them. Version 2 added metadata keys only
# (``success_verdict``, ``last_step_success``): a version-1 file reads as before, without them.
SUPPORTED_SCHEMA_VERSIONS = frozenset({1, 2, 3, 4, 5, 6})


@dataclass
class Episode:
    """One episode as numpy arrays.

    topics: {topic: {field: (T_topic, ...) array}}, each with ``log_time_ns`` (T_topic,) int64: episode time, the
        file's log time minus its ``log_time_origin_ns`` (schema 6 files log at wall-clock time; older ones from 0).
    final: fields of the observation after the last action (``observation``, ...), or {}.
    metadata: the parsed ``episode`` record (or ``episode_start`` of a cut-off file).
    """

    path: Path
    metadata: dict
    topics: dict[str, dict[str, np.ndarray]]
    final: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, topic: str) -> dict[str, np.ndarray]:
        return self.topics[topic]

    def __contains__(self, topic: str) -> bool:
        return topic in self.topics

    @property
    def length(self) -> int:
        return int(self.metadata.get(S.KEY_LENGTH, len(self.topics.get(S.TOPIC_STEP, {}).get("log_time_ns", []))))

    @property
    def points(self) -> np.ndarray:
        """(T, N, 3) float32 tool clouds, metres, hand_base."""
        return self.topics[S.TOPIC_POINTS]["points"]

    def time_s(self, topic: str = S.TOPIC_STEP) -> np.ndarray:
        """Episode times of a topic's messages in seconds (simulated time, from the episode's start)."""
        return self.topics[topic]["log_time_ns"] / 1e9


class EpisodeFile:
    """An open episode file with its MCAP summary; the source of every read."""

    def __init__(self, path, validate: bool = True):
        self.path = Path(path)
        self.validate = validate
        reason = unreadable_reason(self.path)
        if reason is not None:
            raise (DatasetError(f"{self.path}: no such episode file; check the path") if reason == "does not exist"
                   else unreadable_error(self.path, reason))
        self._stream = open(self.path, "rb")
        self._reader = None
        self._raw_metadata = None
        try:
            self.summary = mcap_raw.read_summary(self._stream, validate_crc=validate)
        except mcap_raw.CutOffError as exc:
            self.close()
            raise DatasetError(
                f"{self.path} is cut off ({exc}: the writer stopped before closing it); "
                f"salvage it with: hingelab datasets recover {self.path} --out NEWFILE"
            ) from exc
        except (ValueError, struct.error, UnicodeDecodeError) as exc:
            self.close()
            if "CRC" in str(exc):
                raise corrupt_error(self.path, exc) from exc
            raise DatasetError(f"{self.path} is not a valid MCAP file ({exc}); "
                               "move it out of episodes/ or replace it") from exc
        self.channels = {c.topic: c for c in self.summary.channels.values()}
        self._check_schemas()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stream.close()

    def _check_schemas(self) -> None:
        for channel in self.summary.channels.values():
            schema = self.summary.schemas.get(channel.schema_id)
            expected = S.TOPIC_TYPES.get(channel.topic)
            name = schema.name if schema else "(no schema)"
            if schema is None or schema.encoding != "protobuf" or expected is None \
                    or name != expected.DESCRIPTOR.full_name:
                want = expected.DESCRIPTOR.full_name if expected else "none: not a hingelab topic"
                raise DatasetError(
                    f"{self.path}: topic {channel.topic!r} has foreign schema {name!r} "
                    f"(contract: {want}); this is not a hingelab episode file, move it out of episodes/"
                )

    def raw_metadata(self) -> dict[str, dict[str, str]]:
        """{record name: {key: value}} of all metadata records (the last of each name); read once."""
        if self._raw_metadata is None:
            out = {}
            for name, places in self.summary.metadata_offsets.items():
                for offset, length in places:
                    out[name] = mcap_raw.read_metadata_record(self._stream, offset, length)[1]
            self._raw_metadata = out
        return {name: dict(record) for name, record in self._raw_metadata.items()}

    def metadata(self) -> dict:
        records = self.raw_metadata()
        record = records.get(S.METADATA_EPISODE) or records.get(S.METADATA_EPISODE_START)
        if record is None:
            raise DatasetError(f"{self.path} has no 'episode' metadata record; it was not written "
                               "by EpisodeWriter: rewrite it with hingelab.episodes.EpisodeWriter")
        meta = parse_metadata(record)
        version = meta.get(S.KEY_SCHEMA_VERSION, 1)
        if version not in SUPPORTED_SCHEMA_VERSIONS:
            raise DatasetError(f"{self.path} uses episode schema version {version}; this hingelab reads "
                               f"{sorted(SUPPORTED_SCHEMA_VERSIONS)}: upgrade hingelab")
        return meta

    def channel_info(self, topic: str, key: str) -> dict | None:
        channel = self.channels.get(topic)
        if channel is None or key not in channel.metadata:
            return None
        return json.loads(channel.metadata[key])

    def chunks_of(self, topic: str) -> tuple[list, bool]:
        """Chunk indexes holding ``topic`` and whether all of them hold nothing else."""
        channel_id = self.channels[topic].id
        found = [c for c in self.summary.chunks if channel_id in c.channel_ids]
        return found, all(c.channel_ids == {channel_id} for c in found)

    def columns(self) -> dict[str, np.ndarray] | None:
        """The packed ``/episode/columns`` arrays (``*:log_time_ns`` as episode times), or None if it has none."""
        if S.TOPIC_COLUMNS not in self.channels:
            return None
        chunk_indexes, _ = self.chunks_of(S.TOPIC_COLUMNS)
        channel_id = self.channels[S.TOPIC_COLUMNS].id
        for chunk_index in chunk_indexes:
            records = mcap_raw.read_chunk_records(self._stream, chunk_index, validate_crc=self.validate)
            for _, start, end in mcap_raw.message_spans(records, channel_id):
                message = S.EpisodeColumns.FromString(bytes(records[start:end]))
                columns = {c.name: np.frombuffer(c.data, dtype=c.dtype).reshape(tuple(c.shape))
                           for c in message.columns}
                origin = self.time_origin_ns
                if origin:  # log times -> episode times
                    for name in [n for n in columns if n.endswith(":log_time_ns")]:
                        columns[name] = columns[name] - origin
                return columns
        return None

    def clouds(self) -> tuple[np.ndarray, np.ndarray]:
        """(episode time ns (T,), points (T, N, 3) float32) of every ``/tool/points`` message."""
        times, points = self._clouds_log_time()
        return times - self.time_origin_ns, points

    def _clouds_log_time(self) -> tuple[np.ndarray, np.ndarray]:
        """(log_time_ns (T,) as stored, points (T, N, 3) float32) of every ``/tool/points`` message.

        Fast path (cloud-only chunks with message indexes, as ``EpisodeWriter`` writes
        them): the chunks are decompressed in parallel (``mcap_raw.ChunkBatch``),
        each message's end is found from the chunk's MessageIndex and its record length,
        and the last 12 N bytes of each payload (after the ``data`` field's tag and length,
        checked) are the points: no message is decoded. A message laid out differently is
        decoded with protobuf.
        """
        shapes = self.channel_info(S.TOPIC_POINTS, S.CHANNEL_SHAPES_KEY)
        chunk_indexes, cloud_only = self.chunks_of(S.TOPIC_POINTS)
        if not shapes or not cloud_only:
            fields = self._decode_topics([S.TOPIC_POINTS])[S.TOPIC_POINTS]
            return fields["log_time_ns"], fields["points"]
        n_points = shapes["points"][0]
        n_bytes = 12 * n_points
        prefix = codec.cloud_data_prefix(n_points)
        channel_id = self.channels[S.TOPIC_POINTS].id
        # validating: the positions come from the records (under the chunk's CRC), not the MessageIndex
        index_of = None if self.validate else channel_id
        with mcap_raw.ChunkBatch(self._stream, chunk_indexes, validate_crc=self.validate, index_of=index_of) as batch:
            chunks = iter(batch)
            indexes = batch.indexes
            if self.validate:
                chunks = list(chunks)  # the records stay valid until the batch closes
                indexes = [_record_index(records, channel_id) for records in chunks]
            if any(index is None for index in indexes):  # no message indexes: walk the records
                return self._walk_clouds(chunks, channel_id, n_points)
            times = (np.concatenate([index["log_time"] for index in indexes]).astype(np.int64)
                     if indexes else np.zeros(0, dtype=np.int64))
            points = np.empty((len(times), n_points, 3), dtype="<f4")
            rows = points.reshape(len(times), -1).view(np.uint8)  # (T, 12 N) bytes
            row = 0
            for records, index in zip(chunks, indexes):
                starts = index["offset"].astype(np.int64)
                ends = mcap_raw.record_ends(records, starts)
                data_starts = ends - n_bytes
                if not (mcap_raw.all_preceded_by(records, data_starts, prefix)
                        and np.all(data_starts >= starts + 9 + 22)):
                    self._copy_clouds_decoding(records, starts + 9 + 22, ends, n_points, points[row:])
                else:
                    _gather_rows(records, data_starts, n_bytes, rows[row:row + len(data_starts)])
                row += len(index)
        if len(times) > 1 and np.any(np.diff(times) < 0):
            order = np.argsort(times, kind="stable")
            times, points = times[order], points[order]
        return times, points

    @staticmethod
    def _copy_clouds_decoding(records, starts, ends, n_points: int, out: np.ndarray) -> None:
        """Clouds of a chunk not laid out as EpisodeWriter writes it: decode each message."""
        view = memoryview(records)
        for i, (start, end) in enumerate(zip(starts.tolist(), ends.tolist())):
            message = S.PointCloud.FromString(bytes(view[start:end]))
            out[i] = codec.decode_point_cloud(message).reshape(n_points, 3)

    def _walk_clouds(self, chunks, channel_id: int, n_points: int) -> tuple[np.ndarray, np.ndarray]:
        times, clouds = [], []
        for records in chunks:
            for log_time, start, end in mcap_raw.message_spans(records, channel_id):
                message = S.PointCloud.FromString(bytes(records[start:end]))
                clouds.append(codec.decode_point_cloud(message).astype("<f4").reshape(n_points, 3))
                times.append(log_time)
        times = np.asarray(times, dtype=np.int64)
        points = np.stack(clouds) if clouds else np.zeros((0, n_points, 3), dtype="<f4")
        order = np.argsort(times, kind="stable")
        return times[order], points[order]

    @property
    def time_origin_ns(self) -> int:
        """Wall-clock ns of episode time 0 (``log_time_origin_ns``, schema 6; 0 in older files, whose log times
        start from 0): a message's log time minus it is its episode time."""
        records = self.raw_metadata()
        record = records.get(S.METADATA_EPISODE) or records.get(S.METADATA_EPISODE_START) or {}
        return int(record.get(S.KEY_LOG_TIME_ORIGIN, 0) or 0)

    def iter_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, object]]:
        """(topic, episode time ns, decoded protobuf message) in log-time order (mcap's reader); the episode
        time is the log time minus ``time_origin_ns``."""
        origin = self.time_origin_ns
        for topic, log_time, message in self._raw_messages(topics):
            yield topic, log_time - origin, message

    def _raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, object]]:
        """(topic, log time ns as stored, decoded protobuf message) in log-time order."""
        if self._reader is None:
            self._stream.seek(0)
            self._reader = make_reader(self._stream, validate_crcs=self.validate)
        for _, channel, message in self._reader.iter_messages(topics=topics):
            cls = S.TOPIC_TYPES[channel.topic]
            yield channel.topic, message.log_time, cls.FromString(message.data)

    def _decode_topics(self, topics: Iterable[str] | None = None) -> dict:
        wanted = [t for t in (topics or self.channels) if t in self.channels and t != S.TOPIC_COLUMNS]
        return stack_messages(self._raw_messages(wanted), self._dtypes())[0]

    def _dtypes(self) -> dict[str, dict]:
        return {t: self.channel_info(t, S.CHANNEL_DTYPES_KEY) for t in self.channels}

    def check_digests(self, columns: dict[str, np.ndarray]) -> None:
        """Compare the metadata records with the CRC32s stored in the columns (if the writer stored any)."""
        records = self.raw_metadata()
        prefix = S.DIGEST_COLUMNS + ":"
        for name, stored in columns.items():
            if not name.startswith(prefix):
                continue
            record = records.get(name[len(prefix):])
            if record is None or metadata_digest(record) != int(np.asarray(stored).reshape(-1)[0]):
                raise ValueError(f"its {name[len(prefix):]!r} metadata record fails its CRC check")


def _record_index(records, channel_id: int) -> np.ndarray:
    """(log_time, offset) of the channel's message records, walked from the chunk's own records."""
    spans = mcap_raw.message_spans(records, channel_id)
    index = np.empty(len(spans), dtype=mcap_raw.MESSAGE_INDEX_ENTRY)
    if spans:
        index["log_time"] = [t for t, _, _ in spans]
        index["offset"] = [start - 9 - mcap_raw.MESSAGE_HEAD_SIZE for _, start, _ in spans]
    return index


def stack_messages(messages: Iterable[tuple[str, int, object]],
                   dtypes: dict[str, dict | None]) -> tuple[dict, dict]:
    """Decoded per-step messages -> ({topic: {field: stacked array}}, final observation fields).

    Used by the generic read path and by recover, which has no columns to read.
    """
    rows: dict[str, dict[str, list]] = {}
    final: dict[str, np.ndarray] = {}
    for topic, log_time, message in messages:
        if topic == S.TOPIC_STEP and message.final:
            step_dtypes = dtypes.get(topic)
            for name, value in codec.decode_message(topic, message).items():
                dtype = (step_dtypes or {}).get(name)
                final[name] = value.astype(dtype) if dtype else value
            continue
        if topic in S.VIEWER_TOPICS:  # viewer copies (/tf, /scene): no arrays of their own
            continue
        fields = codec.cast_fields(codec.decode_message(topic, message), dtypes.get(topic))
        topic_rows = rows.setdefault(topic, {"log_time_ns": []})
        topic_rows["log_time_ns"].append(log_time)
        for name, value in fields.items():
            topic_rows.setdefault(name, []).append(value)
    stacked = {}
    for topic, fields in rows.items():
        stacked[topic] = {name: (np.asarray(values, dtype=np.int64) if name == "log_time_ns" else np.stack(values))
                          for name, values in fields.items()}
    return stacked, final


def columns_to_topics(columns: dict[str, np.ndarray]) -> tuple[dict, dict]:
    """Split ``<topic>:<field>`` columns into per-topic dicts and the final observation."""
    topics: dict[str, dict[str, np.ndarray]] = {}
    final: dict[str, np.ndarray] = {}
    for name, array in columns.items():
        topic, _, field_name = name.rpartition(":")
        if topic == S.DIGEST_COLUMNS:  # the metadata records' CRCs, not data
            continue
        if topic == S.TOPIC_STEP and field_name.startswith("final."):
            final[field_name[len("final."):]] = array[0]
        else:
            topics.setdefault(topic, {})[field_name] = array
    return topics, final


def read_episode(path, topics: Iterable[str] | None = None, generic: bool = False,
                 validate: bool = True) -> Episode:
    """Read an episode file into arrays (all topics, or only ``topics``).

    ``generic=True`` skips the fast path and decodes every message (used to test
    that both give the same arrays, and for files from other writers). ``validate``: see the
    module docstring; any failure to read raises ``DatasetError``.
    """
    try:
        return _read_episode(path, topics, generic, validate)
    except DatasetError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever a corrupt file makes a decoder raise
        raise corrupt_error(path, exc) from exc


def unreadable_error(path, reason: str) -> DatasetError:
    """The one-line error of an episode file that cannot even be opened (``bounded_reads.unreadable_reason``)."""
    return DatasetError(f"{path} {reason}; restore what it points to, or remove it")


def corrupt_error(path, exc: BaseException) -> DatasetError:
    """The one-line error of an episode file that cannot be read."""
    path = Path(path)
    dataset = path.parent.parent if path.parent.name == "episodes" else path.parent
    return DatasetError(f"{path} is corrupt ({type(exc).__name__}: {exc}); list the bad files with "
                        f"`hingelab datasets verify {dataset}`, salvage this one with "
                        f"`hingelab datasets recover {path} --out NEWFILE`, or move it out of episodes/")


def _read_episode(path, topics, generic: bool, validate: bool) -> Episode:
    wanted = None if topics is None else set(topics)
    with EpisodeFile(path, validate=validate) as episode_file:
        metadata = episode_file.metadata()
        columns = episode_file.columns() if (validate or not generic) else None
        if columns is not None and validate:
            episode_file.check_digests(columns)
        if generic:
            columns = None
        if columns is None:
            arrays, final = stack_messages(
                episode_file.iter_messages([t for t in episode_file.channels
                                            if t != S.TOPIC_COLUMNS and (wanted is None or t in wanted)]),
                episode_file._dtypes(),
            )
            for topic in S.VIEWER_TOPICS:
                arrays.pop(topic, None)
        else:
            arrays, final = columns_to_topics(columns)
            points_wanted = wanted is None or S.TOPIC_POINTS in wanted
            if points_wanted and S.TOPIC_POINTS in episode_file.channels:
                times, points = episode_file.clouds()
                arrays[S.TOPIC_POINTS] = {"log_time_ns": times, "points": points}
            else:
                arrays.pop(S.TOPIC_POINTS, None)
            if wanted is not None:
                arrays = {t: v for t, v in arrays.items() if t in wanted}
    return Episode(path=Path(path), metadata=metadata, topics=arrays, final=final)


__all__ = ["Episode", "EpisodeFile", "corrupt_error", "unreadable_error", "read_episode", "stack_messages",
           "columns_to_topics", "SUPPORTED_SCHEMA_VERSIONS"]


def _gather_rows(records, starts: np.ndarray, n_bytes: int, out: np.ndarray) -> None:
    """Copy ``n_bytes`` from each of ``starts`` in ``records`` into the rows of ``out``.

    Evenly spaced starts are copied by one strided assignment of ``n_bytes``-wide void
    items (a memcpy per row); otherwise by memoryview slices (a byte-wise numpy gather is
    much slower).
    """
    if len(starts) == 0:
        return
    row = np.dtype((np.void, n_bytes))
    target = out.reshape(len(starts), n_bytes).view(row).reshape(len(starts))
    gaps = np.diff(starts)
    if len(gaps) == 0 or np.all(gaps == gaps[0]):
        stride = int(gaps[0]) if len(gaps) else n_bytes
        target[:] = np.ndarray((len(starts),), dtype=row, buffer=records, offset=int(starts[0]), strides=(stride,))
    else:  # record sizes differ by a few bytes (varint timestamps): slice copies
        source, rows = memoryview(records), memoryview(out.reshape(-1))
        for k, start in enumerate(starts.tolist()):
            rows[k * n_bytes:(k + 1) * n_bytes] = source[start:start + n_bytes]
