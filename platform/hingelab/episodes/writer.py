"""``EpisodeWriter``: one rollout -> one MCAP episode file, written safely.

Usage (what a recording wrapper does per 20 Hz control step)::

    create_dataset(root, name="demos", source="heuristic", config=cfg, seed=0)
    with EpisodeWriter(root, source="heuristic", task="grasp", object="sphere", seed=3) as ep:
        ep.write_step(t, points_hand=cloud, tool_pose_hand=(p, q), joint_position=q9, ...,
                      transition=dict(observation=o, action=a, reward=r,
                                      terminated=False, truncated=False, info={"is_success": 0.0}))
        ...
        ep.write_final_observation(o_last)
        ep.set_outcome(success=True)
    ep.path  # episodes/<episode_id>.mcap

File layout (the performance design, see datasets/README.md):

- every step is a set of standard protobuf messages (one per topic), so viewers
  show every step, logged at the episode's wall-clock start (``log_time_origin_ns``) plus
  the step's time; a step with an object, target, tips or platform also logs ``/scene``;
- steps are buffered in blocks of ``chunk_bytes``; a block is written as MCAP chunks
  holding only ``/tool/points`` (split into equal chunks of at most
  ``cloud_chunk_bytes`` of points, which readers decompress in parallel) and one
  chunk holding the other per-step topics, so a learner reads clouds by slicing
  float32 bytes out of cloud-only chunks without decoding a message;
- each chunk has its own compression (``cloud_compression`` for cloud chunks,
  ``compression`` for the rest; both zstd by default, which keeps files no larger
  than h5py/parquet); ``mcap_raw.ChunkWriter`` writes the file;
- at close, one ``/episode/columns`` message holds every per-step field except the
  clouds as packed column arrays (``hingelab.EpisodeColumns``): the learner reads a
  whole episode's transitions from that one message.

Safety: the file is written as ``episodes/<id>.mcap.partial``; only ``close()``
(after ``finish``, flush and fsync) renames it to ``<id>.mcap``. Names carry a
random part, so any number of processes can write into one dataset at once. If
the ``with`` block raises, the partial file is deleted (default) or, with
``keep_partial_on_error=True``, left on disk for ``hingelab datasets recover``.
A process killed mid-episode leaves its ``.partial`` file: everything in blocks
already written is recoverable.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import time
import uuid
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from mcap_protobuf.schema import register_schema

from hingelab.episodes import codec, mcap_raw
from hingelab.episodes import scene as scene_topic
from hingelab.episodes import schemas as S
from hingelab.episodes.card import CARD_FILE, EPISODES_DIR, load_card
from hingelab.episodes.metadata import digest_columns, format_metadata
from hingelab.provenance import code_version
from hingelab.safe_names import safe_file_name

PARTIAL_SUFFIX = ".partial"
COMPRESSIONS = mcap_raw.COMPRESSIONS  # "zstd", "lz4", "none"


def new_episode_id(source: str) -> str:
    """``<source>-<UTC time>-<12 random hex>``: sortable by time, unique across processes."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%S")
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", source)[:64].strip(".") or "episode"  # a source may come from data
    return f"{safe}-{stamp}-{uuid.uuid4().hex[:12]}"


def column_name(topic: str, field: str) -> str:
    """Name of a packed column in ``/episode/columns``: ``<topic>:<field>``."""
    return f"{topic}:{field}"


class EpisodeWriter:
    """Writes one episode into ``dataset_dir/episodes/`` (see the module docstring).

    Args:
        dataset_dir: a dataset folder made by ``create_dataset`` (it has dataset.json).
        source, task, object, seed, attempt: episode facts for the ``episode`` record.
        config_hash: hash of the producing config; default: the dataset card's.
        time_offset_s: added to every step time: episode time = offset + t (``start_time_s`` is the offset).
        log_time_origin_ns: wall-clock ns (Unix epoch) of episode time 0; every log and publish time is
            this + episode time, so viewers (Foxglove) show when the episode ran. Default: now
            (``time.time_ns()`` at construction). Recorded as ``log_time_origin_ns``; readers subtract it.
        joint_names: names of the 9 hand DoF on ``/hand/joints``.
        action_level: ``"low"`` (9-D joint deltas) or ``"high"`` (5-D), recorded on ``/action``.
        chunk_bytes: block size; a block becomes its cloud chunks and one chunk of the rest.
        compression: of the chunks of the other topics and the columns: ``"zstd"`` (default),
            ``"lz4"`` or ``"none"``.
        cloud_compression: of the cloud chunks; default: ``compression``. ``"zstd"`` keeps
            files smaller than h5py/parquet (float32 clouds shrink a little); ``"none"`` reads
            faster on one core but makes files larger (see datasets/README.md; measured in
            analysis/bench/datasets.md).
        cloud_chunk_bytes: a block's clouds are split into equal chunks of at most this many
            point bytes (320 KiB: two chunks for a 200-step episode of 256-point clouds), so
            that readers decompress them on several cores.
        flush_every_steps: also write a block every this many steps (bounds what a crash loses).
        keep_partial_on_error: keep the ``.partial`` file if the ``with`` block raises.
        extra_metadata: more string facts for the ``episode`` record.
    """

    def __init__(self, dataset_dir, *, source: str, task: str = "", object: str = "",
                 seed: int | None = None, attempt: int = 1, config_hash: str | None = None,
                 time_offset_s: float = 0.0, log_time_origin_ns: int | None = None,
                 joint_names=S.SVH_JOINT_NAMES, action_level: str = "",
                 episode_id: str | None = None, chunk_bytes: int = 4 << 20, compression: str = "zstd",
                 cloud_compression: str | None = None, cloud_chunk_bytes: int = 320 << 10,
                 flush_every_steps: int | None = None, keep_partial_on_error: bool = False,
                 extra_metadata: Mapping | None = None):
        self.dataset_dir = Path(dataset_dir)
        card = load_card(self.dataset_dir)  # refuses a folder without dataset.json
        self.episode_id = safe_file_name(episode_id, "episode_id", self.dataset_dir) if episode_id else \
            new_episode_id(source)
        self.path = self.dataset_dir / EPISODES_DIR / f"{self.episode_id}.mcap"
        self.partial_path = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.facts = {
            S.KEY_EPISODE_ID: self.episode_id, S.KEY_SOURCE: source, S.KEY_TASK: task,
            S.KEY_OBJECT: object, S.KEY_SEED: seed, S.KEY_ATTEMPT: attempt,
            S.KEY_CONFIG_HASH: config_hash if config_hash is not None else card.config_hash,
            S.KEY_SCHEMA_VERSION: S.SCHEMA_VERSION, S.KEY_START_TIME: float(time_offset_s),
            S.KEY_CREATED: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            S.KEY_JOINT_NAMES: list(joint_names), S.KEY_ACTION_LEVEL: action_level or None,
            **code_version(), **dict(extra_metadata or {}),
        }
        self.joint_names = tuple(joint_names)
        self.log_time_origin_ns = time.time_ns() if log_time_origin_ns is None else int(log_time_origin_ns)
        self.facts[S.KEY_LOG_TIME_ORIGIN] = self.log_time_origin_ns
        # the log time of episode time 0 (the origin) plus the offset; every log time below is it + t
        self.time_offset_ns = self.log_time_origin_ns + round(time_offset_s * 1e9)
        self._scene = scene_topic.SceneEncoder()
        self._object_extent = None  # the camera's last object extent (3,) m: the scene's object size if none recorded
        self.chunk_bytes = int(chunk_bytes)
        self.flush_every_steps = flush_every_steps
        self.keep_partial_on_error = keep_partial_on_error
        cloud_compression = compression if cloud_compression is None else cloud_compression
        for name, value in (("compression", compression), ("cloud_compression", cloud_compression)):
            if value not in COMPRESSIONS:
                raise ValueError(f"{name} must be one of {list(COMPRESSIONS)}, not {value!r}")
        self.compression, self.cloud_compression = compression, cloud_compression
        self.cloud_chunk_bytes = max(1, int(cloud_chunk_bytes))
        self._file = None
        self._mcap: mcap_raw.ChunkWriter | None = None
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._dtypes: dict[str, dict[str, str]] = {}  # topic -> field -> dtype name
        self._shapes: dict[tuple[str, str], tuple] = {}
        self._columns: dict[tuple[str, str], list] = {}
        self._log_times: dict[str, list[int]] = {}
        self._pending_clouds: list[tuple[int, bytes]] = []
        self._pending_other: list[tuple[str, int, bytes]] = []
        self._pending_bytes = [0, 0]
        self._cloud_seq = 0
        self._steps_since_flush = 0
        self._final: dict[str, np.ndarray] = {}
        self._last_ns: int | None = None
        self.length = 0  # records (write_step calls): the /step index of the next record
        self.transitions = 0  # records with a transition: the episode's steps
        self._reward_sum = 0.0
        self._outcome: dict = {}
        self.closed = False

    # --- lifecycle -------------------------------------------------------------------
    def __enter__(self) -> "EpisodeWriter":
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def open(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # O_EXCL: two writers can never share a file, even with a reused episode_id.
        fd = os.open(self.partial_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._file = os.fdopen(fd, "wb")
        self._mcap = mcap_raw.ChunkWriter(self._file)
        self._mcap.start(profile="", library=f"hingelab {code_version()['hingelab_version']}")
        # Written at once, so a cut-off file still says what it was (recover uses it).
        self._start_record = format_metadata(self.facts)
        self._mcap.add_metadata(S.METADATA_EPISODE_START, self._start_record)
        self._file.flush()

    def set_outcome(self, success: bool, failure_reason: str | None = None,
                    episode_return: float | None = None, **more) -> None:
        """Episode result for the ``episode`` record (return defaults to the reward sum)."""
        self._outcome = {S.KEY_SUCCESS: bool(success), S.KEY_FAILURE_REASON: failure_reason,
                         S.KEY_RETURN: episode_return, **more}

    def close(self) -> Path:
        """Flush, write columns and the ``episode`` record, fsync, rename. Returns the final path."""
        if self.closed:
            return self.path
        self._flush_block()
        facts = dict(self.facts)
        # length = the steps: an env recording's reset record (no transition) is not one
        steps = self.transitions if self.transitions else self.length
        facts.update({S.KEY_LENGTH: steps, S.KEY_RETURN: self._reward_sum, S.KEY_SUCCESS: False,
                      S.KEY_END_TIME: ((self._last_ns or self.time_offset_ns) - self.log_time_origin_ns) / 1e9})
        facts.update({k: v for k, v in self._outcome.items() if v is not None})
        records = {S.METADATA_EPISODE_START: self._start_record, S.METADATA_EPISODE: format_metadata(facts)}
        self._write_columns(digest_columns(records))  # the records' CRCs, where the chunk's CRC covers them
        self._mcap.add_metadata(S.METADATA_EPISODE, records[S.METADATA_EPISODE])
        self._mcap.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.rename(self.partial_path, self.path)
        _fsync_dir(self.path.parent)
        self.closed = True
        return self.path

    def abort(self) -> None:
        """Give up on the episode: delete the partial file, or keep it (flushed) for recover."""
        if self.closed or self._file is None:
            return
        try:
            if self.keep_partial_on_error:
                self._flush_block()
                os.fsync(self._file.fileno())
        finally:
            self._file.close()
            self.closed = True
            if not self.keep_partial_on_error:
                self.partial_path.unlink(missing_ok=True)

    # --- per step --------------------------------------------------------------------------
    def write_step(self, time_s: float, *, points_hand=None, tool_pose_hand=None,
                   joint_position=None, joint_velocity=None, latent_z=None, latent_z_smoothed=None,
                   action=None, goal_z=None, reward_terms: Mapping[str, float] | None = None,
                   object_position_hand=None, target_position_hand=None,
                   privileged: Mapping | None = None, transition: Mapping | None = None,
                   platform_hand=None) -> None:
        """Log one control step at simulated time ``time_s`` (seconds). Every argument is optional.

        points_hand: (N, 3) float32 metres, hand_base. tool_pose_hand: (position (3,) m,
        quaternion (4,) x, y, z, w) in hand_base. joint_position (9,) rad, joint_velocity (9,)
        rad/s. latent_z, latent_z_smoothed: (2,). action: (9,) or (5,). goal_z: (2,).
        reward_terms: {name: signed contribution}; their sum is ``total``.
        object_position_hand, target_position_hand: (3,) metres, hand_base.
        privileged: {hinge_angle (rad), tool_position (3,), tool_orientation (4,) xyzw,
        tip_a (3,), tip_b (3,), object_position (3,), object_orientation (4,),
        contact_count, table_collision} in hand_base, logged at this step's time.
        transition: {observation: (D,) array or {observation, achieved_goal, desired_goal},
        action, reward, terminated, truncated, info: {name: scalar}}.
        platform_hand: (centre (3,) m, orientation (4,) xyzw, size (3,) m) of the platform in hand_base, for /scene.
        A step with an object, target, tips or platform also logs them on /scene (``episodes.scene``).
        """
        t = self.time_offset_ns + round(time_s * 1e9)
        if self._last_ns is not None and t < self._last_ns:
            raise ValueError(f"step time {time_s} s goes back in time (log times must not decrease)")
        self._last_ns = t
        if points_hand is not None:
            points = np.asarray(points_hand, dtype=np.float32)
            self._field(S.TOPIC_POINTS, "points", points, column=False)
            self._pending_clouds.append((t, codec.encode_point_cloud(t, points)))
            self._pending_bytes[0] += points.nbytes
            self._log_times.setdefault(S.TOPIC_POINTS, []).append(t)
        if tool_pose_hand is not None:
            position, orientation = tool_pose_hand
            self._emit(S.TOPIC_TOOL_POSE, t, codec.encode_pose_in_frame(t, position, orientation),
                       position=position, orientation=orientation)
            self._emit(S.TOPIC_TF, t, codec.encode_frame_transform(t, position, orientation))
        if joint_position is not None:
            velocity = np.zeros(len(self.joint_names)) if joint_velocity is None else joint_velocity
            self._emit(S.TOPIC_JOINTS, t, codec.encode_joint_states(t, self.joint_names, joint_position, velocity),
                       position=joint_position, velocity=velocity)
        if latent_z is not None or latent_z_smoothed is not None:
            fields = _present(z=latent_z, z_smoothed=latent_z_smoothed)
            self._emit(S.TOPIC_LATENT, t, codec.encode_fields(S.ToolLatent, t, **fields), **fields)
        if action is not None:
            payload = codec.encode_fields(S.Action, t, values=action, level=self.facts[S.KEY_ACTION_LEVEL])
            self._emit(S.TOPIC_ACTION, t, payload, values=action)
        if goal_z is not None:
            self._emit(S.TOPIC_GOAL, t, codec.encode_fields(S.LatentGoal, t, z_goal=goal_z), z_goal=goal_z)
        if reward_terms is not None:
            names = list(reward_terms)
            values = [float(reward_terms[n]) for n in names]
            total = float(sum(values))
            payload = codec.encode_fields(S.RewardTerms, t, names=names, values=values, total=total)
            self._emit(S.TOPIC_REWARD, t, payload, **{n: np.float64(v) for n, v in zip(names, values)},
                       total=np.float64(total))
        for topic, position in ((S.TOPIC_OBJECT, object_position_hand), (S.TOPIC_TARGET, target_position_hand)):
            if position is not None:
                self._emit(topic, t, codec.encode_point3(t, position), position=position)
        if privileged is not None:
            fields = _present(**privileged)
            self._emit(S.TOPIC_PRIVILEGED, t, codec.encode_fields(S.PrivilegedState, t, **fields), **fields)
        self._write_scene(t, object_position_hand, target_position_hand, privileged or {}, platform_hand)
        if transition is not None:
            self._write_transition(t, transition)
        self.length += 1
        self._steps_since_flush += 1
        if (max(self._pending_bytes) >= self.chunk_bytes
                or (self.flush_every_steps and self._steps_since_flush >= self.flush_every_steps)):
            self._flush_block()

    def write_camera(self, time_s: float, depth_m, intrinsics, camera_rotation, camera_position,
                     calibration: bool = False) -> None:
        """Log a depth frame (H, W) metres on /camera/depth (16-bit millimetres), the camera's pose in
        hand_base on /camera/pose and, with ``calibration`` (the first frame), /camera/calibration.
        Not in /episode/columns: ``hingelab.episodes.camera_topics.read_camera`` reads them back."""
        t = self.time_offset_ns + round(time_s * 1e9)
        if calibration:
            self._emit(S.TOPIC_CAMERA_CALIBRATION, t, codec.encode_camera_calibration(t, intrinsics))
        self._emit(S.TOPIC_CAMERA_POSE, t, codec.encode_camera_transform(t, camera_rotation, camera_position))
        self._emit(S.TOPIC_DEPTH, t, codec.encode_depth_image(t, depth_m))
        if max(self._pending_bytes) >= self.chunk_bytes:
            self._flush_block()

    def write_object_estimate(self, time_s: float, *, estimator: str, position, extent, n_points: int, fresh: bool,
                              flag: str = "", true_position=None, points=None) -> None:
        """The camera's object estimate (schema 4) on /object/estimate: ``position`` and ``extent`` (3,) m in
        hand_base (the last good ones), ``n_points`` this frame's visible points, ``fresh`` (this frame gave
        the estimate), ``flag`` (why not), ``true_position`` (3,) the simulator's truth (None on a rig); the
        visible points (N, 3) hand_base on /object/points when given (messages only: N varies by frame)."""
        t = self.time_offset_ns + round(time_s * 1e9)
        if np.all(np.isfinite(extent)) and np.all(np.asarray(extent, float) > 0):
            self._object_extent = np.asarray(extent, float)
        fields = _present(position=np.asarray(position, float), extent=np.asarray(extent, float),
                          n_points=np.uint32(n_points), fresh=np.bool_(fresh),
                          true_position=None if true_position is None else np.asarray(true_position, float))
        payload = codec.encode_fields(S.ObjectEstimate, t, estimator=estimator, flag=flag, **fields)
        self._emit(S.TOPIC_OBJECT_ESTIMATE, t, payload, **fields)
        if points is not None:
            self._emit(S.TOPIC_OBJECT_POINTS, t, codec.encode_point_cloud(t, points))

    def write_arm_joints(self, time_s: float, names, position, velocity) -> None:
        """The arm's joints (6, rad and rad/s) on /arm/joints."""
        t = self.time_offset_ns + round(time_s * 1e9)
        self._emit(S.TOPIC_ARM_JOINTS, t, codec.encode_joint_states(t, names, position, velocity),
                   position=np.asarray(position, float), velocity=np.asarray(velocity, float))

    def write_final_observation(self, observation, time_s: float | None = None) -> None:
        """The observation after the last action (for next-observation of the last transition)."""
        t = self._last_ns if time_s is None else self.time_offset_ns + round(time_s * 1e9)
        parts = _observation_parts(observation)
        self._final = {k: np.array(v) for k, v in parts.items()}
        self._pending_other.append(
            (S.TOPIC_STEP, t, codec.encode_fields(S.Step, t, index=self.length, final=True, **parts)))

    def _write_transition(self, t: int, transition: Mapping) -> None:
        fields = dict(_observation_parts(transition["observation"]))
        fields["action"] = transition["action"]
        reward = float(transition["reward"])
        fields.update(reward=np.float64(reward), terminated=np.bool_(transition.get("terminated", False)),
                      truncated=np.bool_(transition.get("truncated", False)))
        info = {str(k): float(v) for k, v in (transition.get("info") or {}).items() if np.isscalar(v)}
        payload = codec.encode_fields(S.Step, t, index=self.length, info_names=list(info),
                                      info_values=list(info.values()), **fields)
        fields.update({"info." + k: np.float64(v) for k, v in info.items()})
        self._reward_sum += reward
        self.transitions += 1
        self._emit(S.TOPIC_STEP, t, payload, **fields)

    def _write_scene(self, t: int, object_position, target_position, privileged: Mapping, platform) -> None:
        """/scene: the step's object, target, tips and platform as SceneUpdate entities (``episodes.scene``)."""
        shape = str(self.facts.get(S.KEY_OBJECT_KIND) or self.facts.get(S.KEY_OBJECT) or "")
        payload = self._scene.encode(
            t, object_position=object_position, object_orientation=privileged.get("object_orientation"),
            object_shape=shape, object_size=self._object_size(), target_position=target_position,
            tip_a=privileged.get("tip_a"), tip_b=privileged.get("tip_b"), platform=platform)
        if payload is not None:
            self._emit(S.TOPIC_SCENE, t, payload)

    def _object_size(self):
        """The object's width (m): the recorded ``object_size``, else the camera's extent (3,), else 2 cm."""
        try:
            size = float(self.facts.get("object_size"))
        except (TypeError, ValueError):
            size = float("nan")
        if np.isfinite(size) and size > 0:
            return size
        return self._object_extent if self._object_extent is not None else scene_topic.DEFAULT_OBJECT_SIZE_M

    # --- internals -----------------------------------------------------------------------
    def _field(self, topic: str, name: str, value, column: bool = True) -> None:
        arr = np.array(value)  # a copy: callers reuse their buffers
        key = (topic, name)
        shape = self._shapes.setdefault(key, arr.shape)
        if arr.shape != shape:
            raise ValueError(f"{topic} field {name!r} changed shape from {shape} to {arr.shape} "
                             f"at step {self.length}; a field keeps one shape within an episode")
        self._dtypes.setdefault(topic, {}).setdefault(name, arr.dtype.str)
        if column:
            self._columns.setdefault(key, []).append(arr)

    def _emit(self, topic: str, t: int, payload: bytes, **fields) -> None:
        for name, value in fields.items():
            self._field(topic, name, value)
        self._log_times.setdefault(topic, []).append(t)
        self._pending_other.append((topic, t, payload))
        self._pending_bytes[1] += len(payload)

    def _channel(self, topic: str) -> int:
        if topic not in self._channel_ids:
            cls = S.TOPIC_TYPES[topic]
            name = cls.DESCRIPTOR.full_name
            if name not in self._schema_ids:
                self._schema_ids[name] = register_schema(self._mcap, cls)
            dtypes = self._dtypes.get(topic, {})
            shapes = {f: list(self._shapes[(topic, f)]) for f in dtypes}
            metadata = {S.CHANNEL_DTYPES_KEY: json.dumps(dtypes, sort_keys=True),
                        S.CHANNEL_SHAPES_KEY: json.dumps(shapes, sort_keys=True)} if dtypes else {}
            self._channel_ids[topic] = self._mcap.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=self._schema_ids[name],
                metadata=metadata,
            )
        return self._channel_ids[topic]

    def _flush_block(self) -> None:
        """Write the buffered steps: cloud-only chunks, then one chunk of the other topics."""
        if self._pending_clouds:
            channel = self._channel(S.TOPIC_POINTS)
            clouds = self._pending_clouds
            n_chunks = -(-self._pending_bytes[0] // self.cloud_chunk_bytes)  # ceil
            bounds = np.linspace(0, len(clouds), min(n_chunks, len(clouds)) + 1).round().astype(int)
            for begin, end in zip(bounds[:-1], bounds[1:]):
                self._mcap.write_chunk([(channel, t, payload, t, self._cloud_seq + i)
                                        for i, (t, payload) in enumerate(clouds[begin:end], begin)],
                                       self.cloud_compression)
            self._cloud_seq += len(clouds)
        if self._pending_other:
            self._mcap.write_chunk([(self._channel(topic), t, payload, t, 0)
                                    for topic, t, payload in self._pending_other], self.compression)
        self._mcap.flush()
        self._pending_clouds, self._pending_other = [], []
        self._pending_bytes = [0, 0]
        self._steps_since_flush = 0

    def _write_columns(self, extra: dict | None = None) -> None:
        columns = {column_name(topic, name): np.stack(values) for (topic, name), values in self._columns.items()}
        columns.update(extra or {})
        for topic, times in self._log_times.items():
            if topic not in S.VIEWER_TOPICS:  # viewer copies (/tf, /scene), not array topics
                columns[column_name(topic, "log_time_ns")] = np.asarray(times, dtype=np.int64)
        for name, value in self._final.items():
            columns[column_name(S.TOPIC_STEP, "final." + name)] = value[None]
        t = self._last_ns if self._last_ns is not None else self.time_offset_ns
        payload = codec.encode_columns(t, self.length, columns)
        self._mcap.write_chunk([(self._channel(S.TOPIC_COLUMNS), t, payload, t, 0)], self.compression)
        self._mcap.flush()


def _present(**fields) -> dict:
    return {k: v for k, v in fields.items() if v is not None}


def _observation_parts(observation) -> dict:
    """A flat observation, or a goal-env dict (observation, achieved_goal, desired_goal)."""
    if isinstance(observation, Mapping):
        unknown = set(observation) - {"observation", "achieved_goal", "desired_goal"}
        if unknown:
            raise ValueError(f"observation dict has keys {sorted(unknown)}; expected observation, "
                             "achieved_goal, desired_goal")
        return {k: observation[k] for k in ("observation", "achieved_goal", "desired_goal") if k in observation}
    return {"observation": observation}


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


__all__ = ["EpisodeWriter", "new_episode_id", "column_name", "PARTIAL_SUFFIX", "CARD_FILE"]
