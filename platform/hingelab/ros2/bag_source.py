"""Opening a ROS 2 bag and reading its streams, whole or what is left of a cut-off one.

``open_bag(path)`` takes a rosbag2 folder (``metadata.yaml`` + MCAP or sqlite3 storage) or a
standalone ``.mcap`` bag and returns a ``Bag``: its topics and types, time range and the raw
messages of the topics asked for, each with its stamp. A healthy bag is read with
``rosbags.highlevel.AnyReader`` (which registers the message definitions the bag stores). An
MCAP bag whose end is missing (a recorder killed mid-chunk: AnyReader refuses it, it needs the
summary at the end) is read record by record with the ``mcap`` library's stream reader until
the cut: every complete chunk is kept, the chunk the cut went through is lost, and the
``Bag.cut_off`` note says so (with the message counts ``metadata.yaml`` promised, if present).

Stamps: a message whose type starts with a ``std_msgs/Header`` (JointState, PointCloud2,
Image, CameraInfo, PoseStamped) is stamped by its header, read from the CDR bytes without
decoding the message (the clouds are large); a zero stamp, and messages without a header
(String, Float64MultiArray), take the bag's log (receive) time.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hingelab.episodes.errors import DatasetError

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
    path: Path
    topics: dict  # topic -> msgtype
    start_ns: int
    end_ns: int
    typestore: object
    raw: dict = field(default_factory=dict)  # topic -> [(log_time_ns, payload)] in log-time order
    cut_off: str | None = None  # why part of the bag was lost, if it was
    lost_messages: dict = field(default_factory=dict)  # topic -> messages metadata.yaml promised that were lost

    @property
    def name(self) -> str:
        return self.path.name

    def deserialize(self, payload: bytes, msgtype: str):
        try:
            return self.typestore.deserialize_cdr(payload, msgtype)
        except Exception as exc:  # rosbags raises its SerdeError and plain struct/index errors
            raise DatasetError(f"{self.path}: a {msgtype} message does not decode ({exc}); the bag is corrupt "
                               "or its stored message definition differs from the data") from None

    def stream(self, topic: str) -> Stream:
        """The topic's messages sorted by stamp (see the module docstring), duplicates of a stamp dropped."""
        msgtype = self.topics[topic]
        messages = self.raw.get(topic, [])
        stamps = np.array([_stamp(payload, log, msgtype) for log, payload in messages], dtype=np.int64)
        order = np.argsort(stamps, kind="stable")
        reordered = int(np.count_nonzero(np.diff(stamps) < 0)) if len(stamps) > 1 else 0
        stamps, payloads = stamps[order], [messages[i][1] for i in order]
        keep = np.ones(len(stamps), bool)
        keep[:-1] = stamps[:-1] != stamps[1:]  # the later of equal stamps wins
        duplicates = int(len(stamps) - keep.sum())
        return Stream(topic, msgtype, stamps[keep], [p for p, k in zip(payloads, keep) if k], reordered, duplicates)


def _stamp(payload: bytes, log_time_ns: int, msgtype: str) -> int:
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


def _promised_counts(path: Path) -> dict:
    """{topic: message count} from a rosbag2 folder's metadata.yaml (empty if none)."""
    meta = path / "metadata.yaml" if path.is_dir() else None
    if meta is None or not meta.exists():
        return {}
    from ruamel.yaml import YAML

    try:
        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"]: int(t["message_count"]) for t in info["topics_with_message_count"]}
    except Exception:  # a malformed metadata.yaml only costs the lost-message counts
        return {}


def open_bag(path, topics=None) -> Bag:
    """Read ``path`` (see the module docstring), keeping the raw messages of ``topics`` (None: all)."""
    from rosbags.highlevel import AnyReader

    path = Path(path)
    if not path.exists():
        raise DatasetError(f"bag {path} does not exist; give a rosbag2 folder (with metadata.yaml) or a .mcap file")
    try:
        with AnyReader([path]) as reader:
            bag = Bag(path, {c.topic: c.msgtype for c in reader.connections}, reader.start_time, reader.end_time,
                      reader.typestore)
            wanted = [c for c in reader.connections if topics is None or c.topic in topics]
            for topic in {c.topic for c in wanted}:
                bag.raw[topic] = []
            if wanted:
                for connection, t, payload in reader.messages(connections=wanted):
                    bag.raw[connection.topic].append((t, bytes(payload)))
            return bag
    except DatasetError:
        raise
    except Exception as exc:  # rosbags' reader errors; an MCAP bag cut off is the case we can still read
        mcap_file = _mcap_file(path)
        if mcap_file is None:
            raise DatasetError(f"bag {path} does not open ({exc}); give a rosbag2 folder (MCAP or sqlite3 "
                               "storage, with metadata.yaml) or a standalone .mcap bag") from None
        return _read_cut_off(path, mcap_file, topics, str(exc))


def _read_cut_off(path: Path, mcap_file: Path, topics, reason: str) -> Bag:
    """Every complete record of an MCAP bag up to where it breaks off."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from rosbags.typesys import get_typestore, Stores, get_types_from_idl, get_types_from_msg

    schemas, channels, raw, types = {}, {}, {}, {}
    first, last, cut = None, None, None
    with open(mcap_file, "rb") as f:
        try:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message) and record.channel_id in channels:
                    channel = channels[record.channel_id]
                    first = record.log_time if first is None else min(first, record.log_time)
                    last = record.log_time if last is None else max(last, record.log_time)
                    if topics is None or channel.topic in topics:
                        raw.setdefault(channel.topic, []).append((record.log_time, bytes(record.data)))
        except Exception as exc:  # the cut: a record or chunk that ends early, or fails its CRC
            cut = f"{type(exc).__name__}: {exc}"
    if cut is None:  # the stream reader read it all: the problem was elsewhere
        raise DatasetError(f"bag {path} does not open ({reason}); give a rosbag2 folder or a .mcap bag")
    for schema in schemas.values():
        text = schema.data.decode("utf-8", "replace")
        try:
            types.update(get_types_from_idl(text) if schema.encoding == "ros2idl" else get_types_from_msg(text, schema.name))
        except Exception as exc:
            raise DatasetError(f"{path}: the message definition of {schema.name} does not parse ({exc})") from None
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(types)
    topic_types = {c.topic: schemas[c.schema_id].name for c in channels.values() if c.schema_id in schemas}
    for messages in raw.values():
        messages.sort(key=lambda m: m[0])
    promised = _promised_counts(path)
    counts = {t: len(m) for t, m in raw.items()}
    lost = {t: n - counts.get(t, 0) for t, n in promised.items() if (topics is None or t in topics)
            and n > counts.get(t, 0)}
    bag = Bag(path, topic_types, first or 0, last or 0, typestore, raw,
              cut_off=f"{mcap_file.name} is cut off ({cut}); kept every complete chunk, up to "
                      f"{(last or 0) / 1e9:.3f} s", lost_messages=lost)
    return bag


__all__ = ["Bag", "Stream", "open_bag"]
