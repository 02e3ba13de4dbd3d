"""Opening a ROS 2 bag and reading its streams, whole or what is left of a cut-off one.

``open_bag(path)`` takes a rosbag2 folder (``metadata.yaml`` + MCAP or sqlite3 storage) or a
standalone ``.mcap`` bag and returns a ``Bag``: its topics, types, counts and time range; its
messages are read in passes (``Bag.messages``), small topics into memory (``Bag.read``), so the
camera's large messages are never all held at once. A healthy bag is read with
``rosbags.highlevel.AnyReader`` (which registers the message definitions the bag stores). An
MCAP bag whose end is missing (a recorder killed mid-chunk: AnyReader refuses it, it needs the
summary at the end) is read record by record with the ``mcap`` library's stream reader until
the cut: every complete chunk is kept, the chunk the cut went through is lost, and the
``Bag.cut_off`` note says so with the messages actually read (and, as the recorder's unchecked
claim, the count ``metadata.yaml`` lists: a file that can say anything is never a drop count).

Stamps: a message whose type starts with a ``std_msgs/Header`` (JointState, PointCloud2,
Image, CameraInfo, PoseStamped) is stamped by its header, read from the CDR bytes without
decoding the message (the clouds are large); a zero stamp, and messages without a header
(String, Float64MultiArray), take the bag's log (receive) time.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from ruamel.yaml import YAML

from hingelab.bounded_reads import unreadable_reason
from hingelab.episodes.errors import DatasetError

METADATA_YAML_MAX_BYTES = 16 << 20  # a rosbag2 metadata.yaml is a few kB; a larger one is not read
HEADER_FIRST = frozenset({
    "sensor_msgs/msg/JointState", "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CameraInfo", "geometry_msgs/msg/PoseStamped",
})


@dataclass
class Stream:
    """One topic's messages in stamp order: ``stamps`` (N,) int64 ns, ``payloads`` raw CDR."""

    topic: str
    msgtype: str
    stamps: np.ndarray
    payloads: list
    reordered: int = 0  # messages that arrived out of stamp order (re-sorted)
    duplicates: int = 0  # messages with a stamp already seen (the later one kept)

    def latest_at_or_before(self, t_ns: int) -> int:
        """Index of the latest message stamped at or before ``t_ns``; -1 if none."""
        return int(np.searchsorted(self.stamps, t_ns, side="right")) - 1

    def __len__(self) -> int:
        return len(self.stamps)


@dataclass
class Bag:
    """An open bag: its topics, types, message counts and time range; messages are read per pass
    (``messages``), so a bag larger than memory is never held whole."""

    path: Path
    topics: dict  # topic -> msgtype
    counts: dict  # topic -> messages
    start_ns: int
    end_ns: int
    typestore: object
    cut_off: str | None = None  # why part of the bag was lost, if it was
    listed_counts: dict = field(default_factory=dict)  # topic -> messages metadata.yaml lists (a cut-off bag)
    mcap_file: Path | None = None  # the file read record by record (a cut-off bag)

    @property
    def name(self) -> str:
        return self.path.name

    def deserialize(self, payload: bytes, msgtype: str):
        try:
            return self.typestore.deserialize_cdr(payload, msgtype)
        except Exception as exc:  # rosbags raises its SerdeError and plain struct/index errors
            raise DatasetError(f"{self.path}: a {msgtype} message does not decode ({exc}); the bag is corrupt "
                               "or its stored message definition differs from the data") from None

    def messages(self, topics) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log time ns, raw CDR) of ``topics`` in the bag's order; one pass over the file."""
        topics = set(topics)
        if self.mcap_file is not None:
            yield from _stream_messages(self.mcap_file, topics)
            return
        with AnyReader([self.path]) as reader:
            wanted = [c for c in reader.connections if c.topic in topics]
            if wanted:
                for connection, t, payload in reader.messages(connections=wanted):
                    yield connection.topic, t, payload

    def read(self, topics) -> dict:
        """{topic: [(log time ns, raw)]} of ``topics`` (small topics only: held in memory)."""
        raw = {t: [] for t in topics if t in self.topics}
        for topic, t, payload in self.messages(raw):
            raw[topic].append((t, bytes(payload)))
        return raw

    def stream(self, topic: str, messages: list) -> Stream:
        """The topic's messages (``read``'s list) sorted by stamp (see the module docstring), duplicates of
        a stamp dropped (the later received kept)."""
        msgtype = self.topics[topic]
        stamps = np.array([message_stamp(payload, log, msgtype) for log, payload in messages], dtype=np.int64)
        order, keep, reordered = sort_stamps(stamps)
        return Stream(topic, msgtype, stamps[order][keep], [messages[i][1] for i in order[keep]], reordered,
                      int(len(stamps) - keep.sum()))


def sort_stamps(stamps: np.ndarray):
    """(order, keep, reordered): a stable sort by stamp, a mask over the sorted messages that keeps the
    last received of equal stamps, and how many messages were stamped before the one received before them."""
    order = np.argsort(stamps, kind="stable")
    reordered = int(np.count_nonzero(np.diff(stamps) < 0)) if len(stamps) > 1 else 0
    ordered = stamps[order]
    keep = np.ones(len(ordered), bool)
    keep[:-1] = ordered[:-1] != ordered[1:]
    return order, keep, reordered


def message_stamp(payload: bytes, log_time_ns: int, msgtype: str) -> int:
    if msgtype in HEADER_FIRST and len(payload) >= 12:
        little = payload[1] & 1  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
        sec, nanosec = struct.unpack_from("<iI" if little else ">iI", payload, 4)
        if sec or nanosec:
            return sec * 1_000_000_000 + nanosec
    return int(log_time_ns)


def _mcap_file(path: Path) -> Path | None:
    if path.is_file():
        return path if path.suffix == ".mcap" else None
    files = sorted(path.glob("*.mcap"))
    return files[0] if len(files) == 1 else None


def _listed_counts(path: Path) -> dict:
    """{topic: message count} as a rosbag2 folder's metadata.yaml states them (empty if none, or if the file
    is larger than any real one): a claim of the recorder, never a count of what a cut-off bag lost."""
    meta = path / "metadata.yaml" if path.is_dir() else None
    if meta is None or unreadable_reason(meta) is not None or meta.stat().st_size > METADATA_YAML_MAX_BYTES:
        return {}
    try:
        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"]: int(t["message_count"]) for t in info["topics_with_message_count"]}
    except Exception:  # a malformed metadata.yaml only costs the lost-message counts
        return {}


def open_bag(path) -> Bag:
    """Open ``path`` (see the module docstring): topics, types, counts, time range; no message is kept."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"bag {path} does not exist; give a rosbag2 folder (with metadata.yaml) or a .mcap file")
    try:
        with AnyReader([path]) as reader:
            counts = {}
            for c in reader.connections:
                counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
            return Bag(path, {c.topic: c.msgtype for c in reader.connections}, counts, reader.start_time,
                       reader.end_time, reader.typestore)
    except Exception as exc:  # rosbags' reader errors; an MCAP bag cut off is the case we can still read
        mcap_file = _mcap_file(path)
        if mcap_file is None:
            raise DatasetError(f"bag {path} does not open ({exc}); give a rosbag2 folder (MCAP or sqlite3 "
                               "storage, with metadata.yaml) or a standalone .mcap bag") from None
        return _open_cut_off(path, mcap_file, str(exc))


def _records(mcap_file: Path):
    """Every complete record of an MCAP file in order, then (None, why) where it breaks off (or (None, None))."""
    with open(mcap_file, "rb") as f:
        try:
            for record in StreamReader(f, validate_crcs=True).records:
                yield record, None
        except Exception as exc:  # the cut: a record or chunk that ends early, or fails its CRC
            yield None, f"{type(exc).__name__}: {exc}".rstrip(": ")
            return
    yield None, None


def _stream_messages(mcap_file: Path, topics: set):
    channels = {}
    for record, _ in _records(mcap_file):
        if isinstance(record, Channel):
            channels[record.id] = record.topic
        elif isinstance(record, Message) and channels.get(record.channel_id) in topics:
            yield channels[record.channel_id], record.log_time, record.data


def _open_cut_off(path: Path, mcap_file: Path, reason: str) -> Bag:
    """The topics, types and counts of an MCAP bag up to where it breaks off."""
    schemas, channels, counts, types = {}, {}, {}, {}
    first, last, cut = None, None, None
    for record, why in _records(mcap_file):
        if record is None:
            cut = why
        elif isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message) and record.channel_id in channels:
            topic = channels[record.channel_id].topic
            counts[topic] = counts.get(topic, 0) + 1
            first = record.log_time if first is None else min(first, record.log_time)
            last = record.log_time if last is None else max(last, record.log_time)
    if cut is None:  # the stream reader read it all: the problem was elsewhere
        raise DatasetError(f"bag {path} does not open ({reason}); give a rosbag2 folder or a .mcap bag")
    for schema in schemas.values():
        text = schema.data.decode("utf-8", "replace")
        try:
            types.update(get_types_from_idl(text) if schema.encoding == "ros2idl"
                         else get_types_from_msg(text, schema.name))
        except Exception as exc:
            raise DatasetError(f"{path}: the message definition of {schema.name} does not parse ({exc})") from None
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(types)
    topic_types = {c.topic: schemas[c.schema_id].name for c in channels.values() if c.schema_id in schemas}
    read = sum(counts.values())
    listed = _listed_counts(path)
    claim = sum(listed.values())
    said = (f"; metadata.yaml lists {claim} (the recorder's count, not checked: the messages after the cut are "
            "not counted as dropped)") if claim > read else ""
    return Bag(path, topic_types, counts, first or 0, last or 0, typestore,
               cut_off=f"{mcap_file.name} is cut off ({cut or 'it ends early'}); kept every complete chunk, up to "
                       f"{(last or 0) / 1e9:.3f} s: {read} messages read{said}", listed_counts=listed,
               mcap_file=mcap_file)


__all__ = ["Bag", "Stream", "open_bag"]
