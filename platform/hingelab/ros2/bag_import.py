"""A ROS 2 bag recorded on the rig -> episodes of a ``real`` dataset.

Per trial (``trials.py``: ``/trial/event`` start..end) one episode: steps at the platform's
20 Hz from the trial's ``start`` (t_k = start + k * 50 ms, while t_k <= end). At each step every
stream is sampled at its **latest message stamped at or before t_k** (``Stream.latest_at_or_before``),
never a later one, and the sample's age t_k - stamp is recorded in the step's infos
(``age_<stream>_s``; see datasets/README.md). Steps before every required stream (joints, a
usable camera cloud) has a sample are left out (the grid stays anchored at ``start``).

The camera: a whole-scene PointCloud2 in the camera frame, or a 32FC1 depth image with its
camera_info. Each camera message is put into ``hand_base`` with the camera's pose from the TF
tree at the message's stamp, then through the platform's camera cloud pipeline
(``perception.camera_cloud``: crop box, statistical outliers, 2 mm voxels, 256 points). A frame
that gives no tool cloud is dropped (counted by its flag) and the step takes the latest frame
that did. The 256-point clouds go through ``ToolState`` (registration, encoder, EMA) as in
simulation: tool pose, latents z and z_bar.

Each episode keeps the bag's name, path, topics and time range in its metadata (``ros2_*``
keys); the summary of a bag (``BagSummary``) counts episodes, steps and the messages dropped
and why.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from hingelab.camera import CameraFrame
from hingelab.episodes import schemas as S
from hingelab.episodes.card import create_dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.writer import EpisodeWriter
from hingelab.perception.camera_cloud import ToolCloudConfig, tool_cloud_from_frame, tool_cloud_from_points, transform
from hingelab.ros2 import ros_messages as M
from hingelab.ros2.bag_source import Bag, Stream, open_bag
from hingelab.ros2.tf_tree import TfTree
from hingelab.ros2.topics import ARM_JOINT_NAMES, KINDS, hand_joint_aliases, topic_names
from hingelab.ros2.trials import Trial, split_trials

STEP_NS = 50_000_000  # 20 Hz
SOURCE = "real"
TASK = "real_trial"
AGE_STREAMS = ("joints", "cloud", "tf", "action", "object")
NAN3 = np.full(3, np.nan)


@dataclass
class BagSummary:
    bag: str
    episodes: list = field(default_factory=list)  # paths
    steps: int = 0
    messages: int = 0  # messages read from the topics used
    dropped: dict = field(default_factory=dict)  # "why" -> count
    notes: list = field(default_factory=list)

    def drop(self, why: str, n: int = 1) -> None:
        if n:
            self.dropped[why] = self.dropped.get(why, 0) + int(n)

    def line(self) -> str:
        dropped = "; ".join(f"{n} {why}" for why, n in self.dropped.items()) or "none"
        notes = "".join(f" Note: {n}." for n in self.notes)
        return (f"{self.bag}: {len(self.episodes)} episodes, {self.steps} steps from {self.messages} messages; "
                f"dropped: {dropped}.{notes}")


def import_config(names: dict, cloud: ToolCloudConfig) -> dict:
    """The dataset card's config: the topics and the cloud pipeline's settings."""
    return {"importer": "ros2", "topics": dict(sorted(names.items())), "tool_cloud": cloud.to_json()}


def import_bags(bags, out, topics=(), progress: bool = False, encoder=None,
                cloud: ToolCloudConfig = ToolCloudConfig()) -> list[BagSummary]:
    """Import every bag of ``bags`` into the dataset folder ``out`` (created, or reopened with the same topics)."""
    from hingelab.perception.encoder import load_encoder

    names = topic_names(topics)
    out = Path(out)
    from hingelab.perception.tool_state import ToolState

    state = ToolState(encoder=encoder or load_encoder(), n_tools=1, dt=STEP_NS / 1e9)  # reset per episode
    return [import_bag(bag, out, names, state, progress=progress, cloud=cloud) for bag in bags]


def _check_topics(bag: Bag, names: dict) -> str:
    """Refuse a bag without the needed topics or with other types; returns the camera kind used."""
    listed = ", ".join(sorted(bag.topics)) or "none"

    def missing(kind: str, extra: str = "") -> DatasetError:
        k = KINDS[kind]
        return DatasetError(f"{bag.path}: no topic {names[kind]} ({k.msgtype}, {k.meaning}){extra}; the bag has "
                            f"{listed}. Name the bag's topic with --topic {kind}=NAME")

    for kind, name in names.items():
        if name in bag.topics and bag.topics[name] != KINDS[kind].msgtype:
            raise DatasetError(f"{bag.path}: topic {name} is {bag.topics[name]}, but the import reads {kind} as "
                               f"{KINDS[kind].msgtype}; point --topic {kind}=NAME at a {KINDS[kind].msgtype} topic")
    for kind in ("joints", "events"):
        if names[kind] not in bag.topics:
            raise missing(kind)
    if names["points"] in bag.topics:
        return "points"
    if names["depth"] in bag.topics:
        if names["camera_info"] not in bag.topics:
            raise missing("camera_info", " for the depth image " + names["depth"])
        return "depth"
    raise missing("points", f" nor a depth image {names['depth']} (--topic depth=NAME)")


class _Camera:
    """Tool clouds from the camera stream, each message processed at most once."""

    def __init__(self, bag: Bag, stream: Stream, kind: str, info: Stream | None, tf: TfTree, cloud: ToolCloudConfig,
                 summary: BagSummary, seed: int):
        self.bag, self.stream, self.kind, self.info, self.tf = bag, stream, kind, info, tf
        self.config, self.summary = cloud, summary
        self.rng = np.random.default_rng(seed)
        self._result: dict[int, tuple | None] = {}  # index -> (cloud, n_distinct, tf stamp) or None
        self._valid_at_or_before: dict[int, int] = {}

    def _process(self, i: int):
        stamp = int(self.stream.stamps[i])
        msg = self.bag.deserialize(self.stream.payloads[i], self.stream.msgtype)
        where = f"{self.bag.path}: {self.stream.topic} at {stamp / 1e9:.3f} s"
        pose = self.tf.lookup("hand_base", msg.header.frame_id, stamp)
        if isinstance(pose, str):
            self.summary.drop(f"camera frames without the camera's pose in hand_base ({pose})")
            return None
        rot, pos, tf_stamp = pose
        if self.kind == "points":
            result = tool_cloud_from_points(transform(M.cloud_xyz(msg, where), rot, pos), self.config, self.rng)
        else:
            j = self.info.latest_at_or_before(stamp)
            if j < 0:
                self.summary.drop("depth images without a camera_info stamped at or before them")
                return None
            intrinsics = M.intrinsics_from_camera_info(self.bag.deserialize(self.info.payloads[j], self.info.msgtype))
            depth = M.depth_image_m(msg, where)
            if depth.shape != (intrinsics.height, intrinsics.width):
                self.summary.drop("depth images whose size differs from their camera_info")
                return None
            frame = CameraFrame(depth, intrinsics, rot, pos, stamp_s=stamp / 1e9)
            result = tool_cloud_from_frame(frame, self.config, self.rng, mask=np.ones(depth.shape, bool))
        if result.points is None:
            self.summary.drop(f"camera frames without a tool cloud in the crop box ({result.flag})")
            return None
        return result.points, result.n_distinct, tf_stamp

    def latest(self, t_ns: int):
        """(index, cloud, n_distinct, tf stamp) of the latest usable frame stamped at or before t_ns, or None."""
        i = self.stream.latest_at_or_before(t_ns)
        visited = []
        while i >= 0:
            if i in self._valid_at_or_before:
                i = self._valid_at_or_before[i]
                break
            if i not in self._result:
                self._result[i] = self._process(i)
            visited.append(i)
            if self._result[i] is not None:
                break
            i -= 1
        for v in visited:
            self._valid_at_or_before[v] = i
        return None if i < 0 else (i, *self._result[i])


class _Joints:
    def __init__(self, bag: Bag, stream: Stream, summary: BagSummary):
        self.bag, self.stream, self.summary = bag, stream, summary
        self._maps: dict[tuple, tuple] = {}
        self._cache: dict[int, tuple] = {}

    def _map(self, names: tuple):
        if names not in self._maps:
            index = {n: i for i, n in enumerate(names)}
            hand = [next((index[a] for a in aliases if a in index), None) for aliases in hand_joint_aliases()]
            if None in hand:
                lost = [aliases[0] for aliases, h in zip(hand_joint_aliases(), hand) if h is None]
                raise DatasetError(f"{self.bag.path}: {self.stream.topic} has no joint(s) {', '.join(lost)}; the hand's "
                                   f"9 channels must carry the platform's names (hingelab.sim.names.HAND_ACTUATORS); "
                                   f"it names {', '.join(names)}")
            arm = [index.get(a) for a in ARM_JOINT_NAMES]
            self._maps[names] = (hand, None if None in arm else arm)
        return self._maps[names]

    def at(self, i: int):
        """(hand q (9,), hand q-dot (9,) or NaN, arm q (6,) or NaN) of message i."""
        if i not in self._cache:
            msg = self.bag.deserialize(self.stream.payloads[i], self.stream.msgtype)
            hand, arm = self._map(tuple(msg.name))
            position, velocity = np.asarray(msg.position, float), np.asarray(msg.velocity, float)
            qdot = velocity[hand] if len(velocity) == len(msg.name) else np.full(9, np.nan)
            self._cache[i] = (position[hand], qdot, position[arm] if arm else np.full(6, np.nan))
        return self._cache[i]


def _events(bag: Bag, name: str) -> list:
    """(log time ns, text) of the event topic in time order (events are stamped by their log time)."""
    msgtype = bag.topics[name]
    return [(t, bag.deserialize(payload, msgtype).data) for t, payload in bag.raw.get(name, [])]


def import_bag(path, out, names: dict, state, progress: bool = False,
               cloud: ToolCloudConfig = ToolCloudConfig()) -> BagSummary:
    """One bag into the dataset ``out`` (created if needed); see the module docstring. ``state``: a ``ToolState``
    (n_tools 1, 20 Hz), reset at every episode."""
    path = Path(path)
    bag = open_bag(path, topics=set(names.values()))
    camera_kind = _check_topics(bag, names)
    # the dataset is made once the first bag is known to fit: a refused bag leaves no empty dataset behind
    create_dataset(out, name=Path(out).name, source=SOURCE, config=import_config(names, cloud),
                   description="real-rig trials imported from ROS 2 bags (hingelab datasets import-ros2)")
    summary = BagSummary(bag.name)
    summary.messages = sum(len(m) for m in bag.raw.values())
    if bag.cut_off:
        summary.notes.append(bag.cut_off)
        for topic, n in bag.lost_messages.items():
            summary.drop(f"{topic} messages lost in the cut-off end of the bag", n)
    streams = {kind: bag.stream(names[kind]) for kind in ("joints", camera_kind, "action", "object", "camera_info")
               if names[kind] in bag.topics and (kind != "camera_info" or camera_kind == "depth")}
    for stream in streams.values():
        if stream.reordered:
            summary.notes.append(f"{stream.reordered} messages on {stream.topic} were stamped earlier than the one "
                                 "before them (non-monotonic stamps); re-ordered by stamp")
        summary.drop(f"{stream.topic} messages with a stamp already seen (the later kept)", stream.duplicates)
    tf = TfTree()
    for kind, static in (("tf_static", True), ("tf", False)):
        for _, payload in bag.raw.get(names[kind], []):
            tf.add(bag.deserialize(payload, bag.topics[names[kind]]), static)
    tf.finish()
    summary.drop("transforms naming a second parent for a frame", tf.reparented)
    trials, notes = split_trials(_events(bag, names["events"]), bag.end_ns)
    summary.notes.extend(notes)
    if not trials:
        summary.notes.append(f"no trial: {names['events']} has no start event")
    joints = _Joints(bag, streams["joints"], summary)
    action = _ActionStream(bag, streams.get("action"), summary)
    total = sum(max(0, (t.end_ns - t.start_ns) // STEP_NS + 1) for t in trials)
    bar = tqdm(total=total, desc=f"import {bag.name}", unit="step", disable=not progress, leave=False)
    try:
        for index, trial in enumerate(trials):
            camera = _Camera(bag, streams[camera_kind], camera_kind, streams.get("camera_info"), tf, cloud, summary,
                             seed=index)
            written = _write_episode(bag, trial, index, out, names, joints, camera, action, streams.get("object"), tf,
                                     state, summary, bar)
            if written is not None:
                summary.episodes.append(written)
    finally:
        bar.close()
    return summary


class _ActionStream:
    """The action topic's values; messages whose length differs from the first one's are dropped."""

    def __init__(self, bag: Bag, stream: Stream | None, summary: BagSummary):
        self.stream, self.values, self.valid = stream, [], None
        if stream is None:
            return
        self.values = [np.asarray(bag.deserialize(p, stream.msgtype).data, float) for p in stream.payloads]
        self.dim = len(self.values[0]) if self.values else 0
        self.valid = np.array([len(v) == self.dim for v in self.values], bool)
        summary.drop(f"{stream.topic} messages whose length differs from the first one's ({self.dim})",
                     int((~self.valid).sum()))
        self.stamps = stream.stamps[self.valid]
        self.values = [v for v, ok in zip(self.values, self.valid) if ok]

    def at(self, t_ns: int):
        """(values, stamp) of the latest action at or before t_ns; (None, None) without a topic or before the first."""
        if self.stream is None or not len(self.values):
            return None, None
        i = int(np.searchsorted(self.stamps, t_ns, side="right")) - 1
        return (None, None) if i < 0 else (self.values[i], int(self.stamps[i]))


def _object_position(bag: Bag, stream: Stream | None, tf: TfTree, t_ns: int):
    """(position (3,) in hand_base, stamp) of the latest object pose at or before t_ns, or (NaN, None)."""
    if stream is None:
        return NAN3, None
    i = stream.latest_at_or_before(t_ns)
    if i < 0:
        return NAN3, None
    msg = bag.deserialize(stream.payloads[i], stream.msgtype)
    stamp = int(stream.stamps[i])
    pose = tf.lookup("hand_base", msg.header.frame_id, stamp)
    if isinstance(pose, str):
        return NAN3, None
    rot, pos, _ = pose
    return rot @ M.pose_pose(msg.pose)[1] + pos, stamp


def _age(t_ns: int, stamp) -> float:
    return np.nan if stamp is None else (t_ns - stamp) / 1e9


def _write_episode(bag, trial: Trial, index: int, out, names, joints: _Joints, camera: _Camera, action: _ActionStream,
                   objects: Stream | None, tf: TfTree, state, summary: BagSummary, bar):
    n_grid = (trial.end_ns - trial.start_ns) // STEP_NS + 1
    if n_grid < 1:
        summary.notes.append(f"trial {index} ends before it starts; skipped")
        return None
    state.reset()
    action_dim = action.dim if action.stream is not None else 5
    has_action = action.stream is not None
    writer = EpisodeWriter(out, source=SOURCE, task=TASK, object="", seed=index, attempt=trial.attempts,
                           action_level="high" if action_dim == 5 else ("low" if action_dim == 9 else ""),
                           extra_metadata={
                               "ros2_bag": bag.name, "ros2_bag_path": str(bag.path.resolve()),
                               "ros2_bag_topics": sorted(bag.topics), "ros2_bag_start_ns": int(bag.start_ns),
                               "ros2_bag_end_ns": int(bag.end_ns), "ros2_trial_index": index,
                               "ros2_trial_start_ns": int(trial.start_ns), "ros2_trial_end_ns": int(trial.end_ns),
                               "ros2_trial_closed_by": trial.closed_by,
                               "ros2_topics_used": [f"{k}={v}" for k, v in sorted(names.items()) if v in bag.topics],
                           })
    skipped = 0
    with writer:
        for k in range(n_grid):
            bar.update(1)
            t = trial.start_ns + k * STEP_NS
            j = joints.stream.latest_at_or_before(t)
            cam = camera.latest(t)
            if j < 0 or cam is None:
                if writer.length == 0:
                    skipped += 1
                    continue
                raise AssertionError("a stream lost its sample mid-episode")  # latest-at-or-before only grows
            q, qdot, arm = joints.at(j)
            cam_index, points, n_distinct, tf_stamp = cam
            cam_stamp = int(camera.stream.stamps[cam_index])
            sample = state.update(points[None], n_distinct=n_distinct)
            values, action_stamp = action.at(t)
            act = np.full(action_dim, np.nan) if values is None else values
            obj, obj_stamp = _object_position(bag, objects, tf, t)
            position, rotation = sample.position[0], sample.rotation[0]
            success_now = trial.success_ns is not None and trial.success_ns <= t
            attempt_now = 1 + sum(1 for et, text in trial.events if et <= t and text.strip().lower() == "attempt")
            info = {"age_joints_s": _age(t, int(joints.stream.stamps[j])), "age_cloud_s": _age(t, cam_stamp),
                    "age_tf_s": 0.0 if tf_stamp is None else _age(t, tf_stamp),
                    "age_action_s": _age(t, action_stamp), "age_object_s": _age(t, obj_stamp),
                    "cloud_points": float(n_distinct), "is_success": float(success_now), "attempt": float(attempt_now),
                    **{name: float(v) for name, v in zip(ARM_JOINT_NAMES, arm)}}
            last = k == n_grid - 1
            observation = np.concatenate([position, sample.euler_xyz[0], sample.z_smoothed[0], obj, NAN3])
            writer.write_step(
                (t - trial.start_ns) / 1e9, points_hand=points, tool_pose_hand=(position, M.quaternion_xyzw(rotation)),
                joint_position=q, joint_velocity=qdot, latent_z=sample.z[0], latent_z_smoothed=sample.z_smoothed[0],
                action=act if has_action else None, object_position_hand=obj if objects is not None else None,
                transition=dict(observation=observation, action=act, reward=np.nan,
                                terminated=last and trial.closed_by == "end",
                                truncated=last and trial.closed_by != "end", info=info))
        if writer.length == 0:
            writer.abort()
            summary.notes.append(f"trial {index} ({trial.start_ns / 1e9:.3f} s) has no step with joints and a tool "
                                 "cloud at or before it; no episode")
            return None
        failure = None if trial.success else (trial.failure_reason or
                                              ("no_end_event" if trial.closed_by != "end" else "no_success_event"))
        writer.set_outcome(trial.success, failure_reason=failure, attempt=trial.attempts,
                           first_attempt_success=trial.first_attempt_success)
    if skipped:
        summary.notes.append(f"trial {index}: its first {skipped} steps had no joint state or tool cloud stamped at "
                             "or before them; the episode starts at the first step that has both")
    summary.steps += writer.length
    return writer.path


__all__ = ["BagSummary", "import_bags", "import_bag", "STEP_NS", "AGE_STREAMS", "SOURCE", "TASK"]
