"""A ROS 2 bag recorded on the rig -> episodes of a ``real`` dataset.

Per trial (``trials.py``: ``/trial/event`` start..end) one episode: steps at the platform's
20 Hz from the trial's ``start`` (t_k = start + k * 50 ms, while t_k <= end). At each step every
stream is sampled at its **latest message stamped at or before t_k** (``Stream.latest_at_or_before``),
never a later one, and the sample's age t_k - stamp is recorded in the step's infos
(``age_<stream>_s``; see datasets/README.md). Steps before every required stream (joints, a
usable camera cloud) has a sample are left out (the grid stays anchored at ``start``).

The camera: a whole-scene PointCloud2 in the camera frame, or a 32FC1 depth image with its
camera_info; or, in a bag hingelab exported (``bag_export``), its ``/tool/points``: the tool cloud
already in ``hand_base``, taken as it is when it has the pipeline's 256 points (the import of an
export gives back the clouds, tool poses and latents it exported). Its topic is read in passes
(``_Camera``): the stamps first, then only the frames some step takes; the other topics are small
and read once into memory. Each frame is put into
``hand_base`` with the camera's pose from the TF tree at the message's stamp, then through the
platform's camera cloud pipeline (``perception.camera_cloud``: crop box, statistical outliers, 2 mm
voxels, 256 points). A frame that gives no tool cloud is dropped (counted by its flag) and the step
takes the latest frame that did. The 256-point clouds go through ``ToolState`` (registration,
encoder, EMA) as in simulation: tool pose, latents z and z_bar.

The object: ``/object/position`` from the bag's object pose (``_object_position``); or, with
``object_from_cloud`` (``--object-from-cloud ESTIMATOR``), estimated from the same camera frames
(``object_from_cloud.py``: the rig's mask topic or the points over the platform, then the stand-in's
estimator), recorded on ``/object/estimate`` (and ``/object/points``) with the metadata key
``object_perception``, as the stand-in's trials record theirs; a bag's object pose, if it has one, is then
the estimate's ``true_position``. Without the flag, a bag with a scene camera but no object pose imports
without an object (the summary says so, and ``train high`` refuses its episodes naming the flag).

Each episode keeps the bag's name, path, topics and time range in its metadata (``ros2_*``
keys); its seed is the trial's index in the bag, or, for a bag hingelab exported, the seed its
``/hingelab/episode`` message records (with the object and the exported episode's id). The
summary of a bag (``BagSummary``) counts episodes, steps and the messages dropped and why. An import
is idempotent: a trial the dataset holds already (``trial_key``: the bag's topic set and time range
and the trial's own; not the bag's file name, so a renamed or copied bag is the same recording) is
skipped, and the summary says so.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from hingelab.camera import CameraFrame
from hingelab.episodes.card import EPISODES_DIR, create_dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.metadata import format_value
from hingelab.episodes.reader import EpisodeFile
from hingelab.episodes.schemas import KEY_OBJECT_PERCEPTION, METADATA_EPISODE
from hingelab.episodes.writer import EpisodeWriter
from hingelab.folder_lock import LOCK_FILE, entries, is_empty
from hingelab.perception.camera_cloud import ToolCloudConfig, tool_cloud_from_frame, tool_cloud_from_points, transform
from hingelab.perception.encoder import load_encoder
from hingelab.perception.tool_state import ToolState
from hingelab.ros2 import ros_messages as M
from hingelab.ros2.bag_source import Bag, Stream, message_stamp, open_bag, sort_stamps
from hingelab.ros2.object_from_cloud import FrameObject, ObjectFromCloud, ObjectTrack
from hingelab.ros2.tf_tree import TfTree
from hingelab.ros2.topics import ARM_JOINT_NAMES, KINDS, hand_joint_aliases, topic_names
from hingelab.ros2.trials import Trial, split_trials

STEP_NS = 50_000_000  # 20 Hz
SOURCE = "real"
TASK = "real_trial"
AGE_STREAMS = ("joints", "arm_joints", "cloud", "tf", "action", "object")
NAN3 = np.full(3, np.nan)
_MASK_MISSING = b""  # _Camera: a frame whose mask the bag does not hold


@dataclass
class BagSummary:
    bag: str
    episodes: list = field(default_factory=list)  # paths
    steps: int = 0
    messages: int = 0  # messages read from the topics used
    dropped: dict = field(default_factory=dict)  # "why" -> count
    notes: list = field(default_factory=list)
    camera_s: float = 0.0  # seconds in the camera frames' decoding, TF and cloud pipeline (not the bag reads)
    camera_frames: int = 0  # camera frames that went through it (those some step takes)

    def drop(self, why: str, n: int = 1) -> None:
        if n:
            self.dropped[why] = self.dropped.get(why, 0) + int(n)

    def line(self) -> str:
        dropped = "; ".join(f"{n} {why}" for why, n in self.dropped.items()) or "none"
        notes = "".join(f" Note: {n}." for n in self.notes)
        return (f"{self.bag}: {len(self.episodes)} episodes, {self.steps} steps from {self.messages} messages; "
                f"dropped: {dropped}.{notes}")


def import_config(names: dict, cloud: ToolCloudConfig, object_from_cloud: str | None = None) -> dict:
    """The dataset card's config: the topics and the cloud pipeline's settings, and the object estimator with
    ``object_from_cloud``. The mask topic is named only then, so a dataset imported before the kind existed
    (or without the flag) reopens with the same config."""
    topics = {k: v for k, v in sorted(names.items()) if k != "object_mask" or object_from_cloud}
    config = {"importer": "ros2", "topics": topics, "tool_cloud": cloud.to_json()}
    return {**config, "object_from_cloud": object_from_cloud} if object_from_cloud else config


def trial_key(bag_topics, bag_start_ns: int, bag_end_ns: int, trial_start_ns: int, trial_end_ns: int) -> tuple:
    """What identifies an imported trial: its bag's topic set and time range and its own time range, as
    the episode's ``ros2_*`` metadata stores them."""
    return (format_value(sorted(bag_topics)), *(str(int(t)) for t in (bag_start_ns, bag_end_ns, trial_start_ns,
                                                                      trial_end_ns)))


META_KEY = ("ros2_bag_topics", "ros2_bag_start_ns", "ros2_bag_end_ns", "ros2_trial_start_ns", "ros2_trial_end_ns")


def imported_trials(out) -> dict[tuple, str]:
    """The trials the dataset folder ``out`` holds (``trial_key`` -> episode file name); an episode file that
    cannot be read, or was not imported from a bag, names none."""
    episodes = Path(out) / EPISODES_DIR
    found = {}
    for path in sorted(episodes.glob("*.mcap")) if episodes.is_dir() else []:
        try:
            with EpisodeFile(path) as episode_file:
                meta = episode_file.raw_metadata().get(METADATA_EPISODE, {})
        except Exception:  # noqa: BLE001 - a corrupt file is verify's to report; it identifies no trial
            continue
        if all(k in meta for k in META_KEY):
            found.setdefault(tuple(meta[k] for k in META_KEY), path.name)
    return found


def import_bags(bags, out, topics=(), progress: bool = False, encoder=None,
                cloud: ToolCloudConfig = ToolCloudConfig(), object_from_cloud: str | None = None) -> list[BagSummary]:
    """Import every bag of ``bags`` into the dataset folder ``out`` (created, or reopened with the same topics);
    trials ``out`` holds already (by ``trial_key``) are skipped. ``object_from_cloud``: an object estimator
    (``hingelab.perception.object_estimate.ESTIMATORS``) that gives the object from the camera frames, whether
    or not a bag has an object pose (module docstring); None: the object pose, where a bag has one."""
    names = topic_names(topics)
    out = Path(out)
    objects = None if object_from_cloud is None else ObjectFromCloud(object_from_cloud)
    state = ToolState(encoder=encoder or load_encoder(), n_tools=1, dt=STEP_NS / 1e9)  # reset per episode
    created = is_empty(out)  # new, or holding only the command's lock file
    imported = imported_trials(out)
    try:
        return [import_bag(bag, out, names, state, progress=progress, cloud=cloud, imported=imported,
                           objects=objects) for bag in bags]
    except BaseException:
        if created and out.is_dir() and not any((out / EPISODES_DIR).glob("*.mcap")):
            for entry in entries(out):  # a bag refused midway (a malformed message): no empty dataset
                shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)
            if not entries(out) and not (out / LOCK_FILE).exists():
                shutil.rmtree(out, ignore_errors=True)
        raise


def _check_topics(bag: Bag, names: dict) -> str:
    """Refuse a bag without the needed topics or with other types; returns the camera kind used."""
    listed = ", ".join(sorted(bag.topics)) or "none"

    def missing(kind: str, extra: str = "") -> DatasetError:
        k = KINDS[kind]
        cut = f" ({bag.cut_off})" if bag.cut_off else ""
        return DatasetError(f"{bag.path}: no topic {names[kind]} ({k.msgtype}, {k.meaning}){extra}; the bag has "
                            f"{listed}{cut}. Name the bag's topic with --topic {kind}=NAME")

    for kind, name in names.items():
        if name in bag.topics and bag.topics[name] != KINDS[kind].msgtype:
            raise DatasetError(f"{bag.path}: topic {name} is {bag.topics[name]}, but the import reads {kind} as "
                               f"{KINDS[kind].msgtype}; point --topic {kind}=NAME at a {KINDS[kind].msgtype} topic")
    for kind in ("joints", "events"):
        if names[kind] not in bag.topics:
            raise missing(kind)
    if names["points"] in bag.topics:
        return "points"
    if names["tool_points"] in bag.topics:
        return "tool_points"
    if names["depth"] in bag.topics:
        if names["camera_info"] not in bag.topics:
            raise missing("camera_info", " for the depth image " + names["depth"])
        return "depth"
    raise missing("points", f" nor a tool cloud {names['tool_points']} nor a depth image {names['depth']} "
                            "(--topic depth=NAME)")


class _Camera:
    """Tool clouds from the camera topic, read in passes so that its large messages are never held at once.

    The first pass reads every message's stamp (from the CDR header) and sorts them; ``prepare(times)``
    then runs the pipeline on the frames that are the latest at or before some step (and, where one
    gives no tool cloud, on earlier ones until one does), one more pass over the topic each time;
    only the 256-point results are kept. The pipeline's random draw is seeded by the frame's stamp,
    so a frame gives the same cloud whichever steps or bags ask for it.

    With ``objects`` each of those frames also gives the object (``object_at``; ``object_from_cloud.py``),
    from the arm's joints at the frame's stamp (``joints``) and, with ``mask_topic``, the mask stamped as the
    frame, read in the same passes (a frame waits for its mask, a mask for its frame, each only as long as
    the other is still to come).
    """

    def __init__(self, bag: Bag, topic: str, kind: str, info: Stream | None, tf: TfTree, cloud: ToolCloudConfig,
                 summary: BagSummary, progress: bool = False, objects: ObjectFromCloud | None = None,
                 joints=None, mask_topic: str | None = None):
        self.bag, self.topic, self.msgtype, self.kind = bag, topic, bag.topics[topic], kind
        self.info, self.tf, self.config, self.summary, self.progress = info, tf, cloud, summary, progress
        self.objects, self.joints, self.mask_topic = objects, joints, mask_topic
        self._object: dict[int, FrameObject] = {}  # sorted position -> the frame's object (with ``objects``)
        raw = np.array([message_stamp(payload[:12], t, self.msgtype)
                        for _, t, payload in self._pass("stamps", [self.topic])], dtype=np.int64)
        order, keep, reordered = sort_stamps(raw)
        self.stamps, self.ordinals = raw[order][keep], order[keep]  # sorted position -> position in the bag
        self.messages = len(raw)
        if reordered:
            summary.notes.append(f"{reordered} messages on {topic} were stamped earlier than the one before them "
                                 "(non-monotonic stamps); re-ordered by stamp")
        summary.drop(f"{topic} messages with a stamp already seen (the later kept)", int(len(raw) - keep.sum()))
        self._result: dict[int, tuple | None] = {}  # sorted position -> (cloud, n_distinct, tf stamp) or None

    def _pass(self, what: str, topics):
        """One pass over the camera topic (with a progress bar: a rig's camera topic is most of a bag)."""
        return tqdm(self.bag.messages(topics), total=sum(self.bag.counts.get(t, 0) for t in topics),
                    desc=f"{self.bag.name} {self.topic}: {what}", unit="msg", disable=not self.progress, leave=False)

    def _run(self, positions) -> None:
        todo = {int(self.ordinals[p]): p for p in positions if p not in self._result}
        if not todo:
            return
        wanted = {int(self.stamps[p]) for p in todo.values()} if self.mask_topic else set()
        waiting, masks = {}, {}  # stamp -> (position, frame payload) without its mask yet; stamp -> mask payload
        ordinal = -1
        topics = [self.topic, self.mask_topic] if wanted else [self.topic]
        for topic, t, payload in self._pass("tool clouds", topics):
            if topic != self.topic:  # a mask: kept only while the frame of its stamp is still to come
                stamp = message_stamp(bytes(payload[:12]), t, self.bag.topics[topic])
                if stamp in waiting:
                    self._timed(*waiting.pop(stamp), bytes(payload))
                elif stamp in wanted:
                    masks[stamp] = bytes(payload)
                continue
            ordinal += 1
            if ordinal not in todo:
                continue
            p = todo[ordinal]
            stamp = int(self.stamps[p])
            if not wanted:
                self._timed(p, bytes(payload), None)
            elif stamp in masks:
                self._timed(p, bytes(payload), masks.pop(stamp))
            else:
                waiting[stamp] = (p, bytes(payload))
        for p, payload in waiting.values():
            self._timed(p, payload, _MASK_MISSING)

    def _timed(self, p: int, payload: bytes, mask: bytes | None) -> None:
        started = time.perf_counter()
        self._result[p], frame_object = self._process(payload, int(self.stamps[p]), mask)
        if self.objects is not None:
            self._object[p] = frame_object
        self.summary.camera_s += time.perf_counter() - started
        self.summary.camera_frames += 1

    def prepare(self, times_ns: np.ndarray) -> None:
        """Process the frames the steps at ``times_ns`` take (see the class docstring)."""
        needed = {int(p) for p in np.searchsorted(self.stamps, times_ns, side="right") - 1 if p >= 0}
        self._run(needed)
        while True:
            want = set()
            for p in needed:
                while p >= 0 and p in self._result and self._result[p] is None:
                    p -= 1
                if p >= 0 and p not in self._result:
                    want.update(range(max(0, p - 7), p + 1))  # a run of frames without a cloud: 8 at a time
            if not want:
                return
            self._run(want)

    def _process(self, payload: bytes, stamp: int, mask: bytes | None):
        """(tool result or None, the frame's object or None): ``mask`` the mask's payload (None: no mask topic;
        ``_MASK_MISSING``: none for this frame)."""
        msg = self.bag.deserialize(payload, self.msgtype)
        where = f"{self.bag.path}: {self.topic} at {stamp / 1e9:.3f} s"
        pose = self.tf.lookup("hand_base", msg.header.frame_id, stamp)
        if isinstance(pose, str):
            self.summary.drop(f"camera frames without the camera's pose in hand_base ({pose})")
            return None, FrameObject(stamp, flag="no_camera_pose")
        rot, pos, tf_stamp = pose
        rng = np.random.default_rng(stamp)
        arm_q = None if self.objects is None else self.joints.arm_at(stamp)[0]
        frame_object = None
        if self.kind == "tool_points":
            points = transform(M.cloud_xyz(msg, where), rot, pos).astype(np.float32)
            if len(points) == self.config.n_points:  # a hingelab export's tool cloud: the pipeline's output already
                return (points, len(np.unique(points, axis=0)), tf_stamp), None
            result = tool_cloud_from_points(points.astype(np.float64), self.config, rng)
        elif self.kind == "points":
            scene = M.cloud_xyz(msg, where)
            points = near_crop_box(scene, rot, pos, self.config)
            # the scene's size counts as the frame's points: a frame of table alone is "too_few_points",
            # not the "no_tool_pixels" that counting only the pre-cropped points would give
            result = tool_cloud_from_points(transform(points, rot, pos), self.config, rng,
                                            counts={"tool_pixels": len(scene)})
            if self.objects is not None:
                frame_object = self.objects.frame(stamp, (rot, pos), arm_q, scene_points=scene,
                                                  tool_points_hand=result.points)
        else:
            j = self.info.latest_at_or_before(stamp)
            if j < 0:
                self.summary.drop("depth images without a camera_info stamped at or before them")
                return None, FrameObject(stamp, flag="no_camera_info")
            intrinsics = M.intrinsics_from_camera_info(self.bag.deserialize(self.info.payloads[j], self.info.msgtype))
            depth = M.depth_image_m(msg, where)
            if depth.shape != (intrinsics.height, intrinsics.width):
                self.summary.drop("depth images whose size differs from their camera_info")
                return None, FrameObject(stamp, flag="depth_size_differs")
            frame = CameraFrame(depth, intrinsics, rot, pos, stamp_s=stamp / 1e9)
            result = tool_cloud_from_frame(frame, self.config, rng, mask=np.ones(depth.shape, bool))
            if self.objects is not None:
                frame_object = self._depth_object(stamp, (rot, pos), arm_q, depth, intrinsics, mask, result.points)
        if result.points is None:
            self.summary.drop(f"camera frames without a tool cloud in the crop box ({result.flag})")
            return None, frame_object
        return (result.points, result.n_distinct, tf_stamp), frame_object

    def _depth_object(self, stamp: int, camera_in_hand, arm_q, depth, intrinsics, mask: bytes | None, tool_points):
        if mask is None:
            return self.objects.frame(stamp, camera_in_hand, arm_q, depth=depth, intrinsics=intrinsics,
                                      tool_points_hand=tool_points)
        if mask == _MASK_MISSING:
            return self.objects.missing_mask(stamp)
        where = f"{self.bag.path}: {self.mask_topic} at {stamp / 1e9:.3f} s"
        pixels = M.mask_image(self.bag.deserialize(mask, self.bag.topics[self.mask_topic]), where)
        if pixels.shape != depth.shape:
            raise DatasetError(f"{where}: the mask is {pixels.shape[1]} x {pixels.shape[0]}, its depth image "
                               f"{depth.shape[1]} x {depth.shape[0]}; a mask segments the depth image pixel for pixel")
        return self.objects.frame(stamp, camera_in_hand, arm_q, depth=depth, intrinsics=intrinsics, mask=pixels)

    def latest(self, t_ns: int):
        """(sorted position, cloud, n_distinct, tf stamp) of the latest usable frame stamped at or before t_ns,
        or None (after ``prepare`` for t_ns)."""
        p = int(np.searchsorted(self.stamps, t_ns, side="right")) - 1
        while p >= 0 and self._result.get(p) is None:
            p -= 1
        return None if p < 0 else (p, *self._result[p])

    def object_at(self, t_ns: int) -> FrameObject | None:
        """The object of the latest frame stamped at or before t_ns (whether or not it gave a tool cloud), or None
        (after ``prepare`` for t_ns, with ``objects``)."""
        p = int(np.searchsorted(self.stamps, t_ns, side="right")) - 1
        return None if p < 0 else self._object.get(p)


def near_crop_box(points: np.ndarray, rot: np.ndarray, pos: np.ndarray, cloud: ToolCloudConfig) -> np.ndarray:
    """The camera-frame points (N, 3) within the sphere around the pipeline's crop box (a box in hand_base,
    the camera there at (rot, pos)): cropping before the transform, since a whole-scene cloud of a real
    camera (~100-250k points) has only a few thousand in the box. Every point of the box is kept (its
    sphere holds it, with a margin for rounding); the pipeline's exact crop follows in hand_base."""
    low, high = np.asarray(cloud.crop_low, float), np.asarray(cloud.crop_high, float)
    centre = rot.T @ (0.5 * (low + high) - pos)  # the box's centre in the camera frame
    radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
    offset = points - centre
    return points[np.einsum("ij,ij->i", offset, offset) <= radius * radius]


class _Joints:
    """The joint states, split by what each message holds: many rigs publish the arm's and the hand's on
    ``/joint_states`` from two drivers. The hand's 9 channels come from the messages that name all of
    them, the arm's 6 joints from those that name all of those; a message with neither is dropped.
    Each part is sorted by stamp and keeps the later of two messages with one stamp, so the two drivers'
    messages of one instant (or a hingelab export's arm and hand messages) are both kept."""

    def __init__(self, bag: Bag, topic: str, messages: list, summary: BagSummary):
        self.topic = topic
        msgtype = bag.topics[topic]
        stamps = np.array([message_stamp(payload, log, msgtype) for log, payload in messages], dtype=np.int64)
        _, _, reordered = sort_stamps(stamps)
        if reordered:
            summary.notes.append(f"{reordered} messages on {topic} were stamped earlier than the one before them "
                                 "(non-monotonic stamps); re-ordered by stamp")
        hand_rows, arm_rows, seen = [], [], set()
        aliases = hand_joint_aliases()
        for stamp, (_, payload) in zip(stamps, messages):
            msg = bag.deserialize(payload, msgtype)
            index = {n: i for i, n in enumerate(msg.name)}
            seen.update(msg.name)
            position, velocity = np.asarray(msg.position, float), np.asarray(msg.velocity, float)
            hand = [next((index[a] for a in names if a in index), None) for names in aliases]
            arm = [index.get(a) for a in ARM_JOINT_NAMES]
            if None not in hand and len(position) == len(msg.name):
                qdot = velocity[hand] if len(velocity) == len(msg.name) else np.full(9, np.nan)
                hand_rows.append((int(stamp), position[hand], qdot))
            if None not in arm and len(position) == len(msg.name):
                arm_rows.append((int(stamp), position[arm]))
            if None in hand and None in arm:
                summary.drop(f"{topic} messages with neither the hand's 9 channels nor arm_joint_1..6")
        hand_rows, arm_rows = _by_stamp(hand_rows), _by_stamp(arm_rows)
        summary.drop(f"{topic} messages with a stamp already seen (the later kept)",
                     len(hand_rows.dropped) + len(arm_rows.dropped))
        if not hand_rows and len(messages):
            lost = [names[0] for names in aliases if not any(n in seen for n in names)]
            raise DatasetError(f"{bag.path}: {topic} has no message with the hand's joint(s) {', '.join(lost)}; "
                               "the hand's 9 channels must carry the platform's names (hingelab.sim.names."
                               f"HAND_ACTUATORS); its messages name {', '.join(sorted(seen))}")
        self.hand_stamps = np.array([r[0] for r in hand_rows], np.int64)
        self.hand = [(r[1], r[2]) for r in hand_rows]
        self.arm_stamps = np.array([r[0] for r in arm_rows], np.int64)
        self.arm = [r[1] for r in arm_rows]

    def __len__(self) -> int:
        return len(self.hand_stamps)

    def hand_at(self, t_ns: int):
        """(q (9,), q-dot (9,), stamp) of the latest hand state at or before t_ns, or None."""
        i = int(np.searchsorted(self.hand_stamps, t_ns, side="right")) - 1
        return None if i < 0 else (*self.hand[i], int(self.hand_stamps[i]))

    def arm_at(self, t_ns: int):
        """(q (6,), stamp) of the latest arm state at or before t_ns, or (NaN, None)."""
        i = int(np.searchsorted(self.arm_stamps, t_ns, side="right")) - 1
        return (np.full(6, np.nan), None) if i < 0 else (self.arm[i], int(self.arm_stamps[i]))


class _Rows(list):
    """Rows sorted by stamp, one per stamp (the later received); ``dropped``: the earlier ones of a stamp."""

    dropped: list


def _by_stamp(rows: list) -> _Rows:
    order, keep, _ = sort_stamps(np.array([r[0] for r in rows], np.int64))
    out = _Rows(rows[i] for i in order[keep])
    out.dropped = [rows[i] for i in order[~keep]]
    return out


def import_bag(path, out, names: dict, state, progress: bool = False,
               cloud: ToolCloudConfig = ToolCloudConfig(), imported: dict | None = None,
               objects: ObjectFromCloud | None = None) -> BagSummary:
    """One bag into the dataset ``out`` (created if needed); see the module docstring. ``state``: a ``ToolState``
    (n_tools 1, 20 Hz), reset at every episode. ``imported``: the trials ``out`` holds (``imported_trials``),
    skipped here; the trials this imports are added to it. ``objects``: the object from the camera frames
    (``--object-from-cloud``), else from the bag's object pose."""
    path = Path(path)
    bag = open_bag(path)
    camera_kind = _check_topics(bag, names)
    mask_topic = _check_object_source(bag, names, camera_kind, objects)
    # the dataset is made once the first bag is known to fit: a refused bag leaves no empty dataset behind
    create_dataset(out, name=Path(out).name, source=SOURCE,
                   config=import_config(names, cloud, None if objects is None else objects.estimator),
                   description="real-rig trials imported from ROS 2 bags (hingelab datasets import-ros2)")
    summary = BagSummary(bag.name)
    if bag.cut_off:  # what was read is counted; metadata.yaml's counts are only quoted in the note
        summary.notes.append(bag.cut_off)
    if objects is None and names["object"] not in bag.topics and camera_kind != "tool_points":
        summary.notes.append(f"no object pose ({names['object']}): the episodes have no object position, which "
                             "train high needs; --object-from-cloud estimates it from the camera frames")
    if objects is not None and names["object_mask"] in bag.topics and mask_topic is None:
        summary.notes.append(f"{names['object_mask']} segments depth images, and the camera here is the cloud "
                             f"{names[camera_kind]}: the object is segmented by the points over the platform")
    small = [k for k in ("joints", "action", "object", "events", "tf", "tf_static", "episode")
             + (("camera_info",) if camera_kind == "depth" else ()) if names[k] in bag.topics]
    raw = bag.read({names[k] for k in small})
    summary.messages = sum(len(m) for m in raw.values())
    streams = {}
    for kind in ("action", "object", "camera_info"):  # the joints are sorted per part (_Joints)
        if kind in small:
            stream = streams[kind] = bag.stream(names[kind], raw[names[kind]])
            if stream.reordered:
                summary.notes.append(f"{stream.reordered} messages on {stream.topic} were stamped earlier than the "
                                     "one before them (non-monotonic stamps); re-ordered by stamp")
            summary.drop(f"{stream.topic} messages with a stamp already seen (the later kept)", stream.duplicates)
    tf = TfTree()
    for kind, static in (("tf_static", True), ("tf", False)):
        for _, payload in raw.get(names[kind], []):
            tf.add(bag.deserialize(payload, bag.topics[names[kind]]), static)
    tf.finish()
    summary.drop("transforms naming a second parent for a frame", tf.reparented)
    events = [(t, bag.deserialize(p, bag.topics[names["events"]]).data) for t, p in raw[names["events"]]]
    trials, notes = split_trials(events, bag.end_ns)
    summary.notes.extend(notes)
    if not trials:
        summary.notes.append(f"no trial: {names['events']} has no start event")
    imported = imported_trials(out) if imported is None else imported
    keys = [trial_key(bag.topics, bag.start_ns, bag.end_ns, t.start_ns, t.end_ns) for t in trials]
    already = [imported[key] for key in keys if key in imported]
    if already:
        shown = ", ".join(already[:3]) + (" ..." if len(already) > 3 else "")
        summary.notes.append(f"{len(already)} trial{'s' if len(already) > 1 else ''} already in {out} (the same "
                             f"topics and time range: {shown}), skipped")
    todo = [(index, trial, key) for index, (trial, key) in enumerate(zip(trials, keys)) if key not in imported]
    joints = _Joints(bag, names["joints"], raw[names["joints"]], summary)
    camera = _Camera(bag, names[camera_kind], camera_kind, streams.get("camera_info"), tf, cloud, summary, progress,
                     objects=objects, joints=joints, mask_topic=mask_topic)
    summary.messages += camera.messages
    grids = [trial.start_ns + STEP_NS * np.arange(max(0, (trial.end_ns - trial.start_ns) // STEP_NS + 1))
             for _, trial, _ in todo]
    if grids:
        camera.prepare(np.concatenate(grids))
    action = _ActionStream(bag, streams.get("action"), summary)
    exported = [(t, _exported_metadata(bag, p, summary)) for t, p in raw.get(names["episode"], [])]
    bar = tqdm(total=sum(len(g) for g in grids), desc=f"import {bag.name}", unit="step", disable=not progress,
               leave=False)
    track = None if objects is None else _ObjectSteps(objects, "mask" if mask_topic else "platform")
    try:
        for index, trial, key in todo:
            recorded = next((m for t, m in reversed(exported) if t <= trial.start_ns), {})
            written = _write_episode(bag, trial, index, out, names, joints, camera, action, streams.get("object"), tf,
                                     state, summary, bar, recorded, track)
            if written is not None:
                summary.episodes.append(written)
                imported[key] = Path(written).name
    finally:
        bar.close()
    if track is not None and track.steps:
        summary.notes.append(track.line())
    return summary


def _check_object_source(bag: Bag, names: dict, camera_kind: str, objects: ObjectFromCloud | None) -> str | None:
    """Refuse ``--object-from-cloud`` on a bag whose camera is only the tool's cloud; the mask topic read with it
    (the bag's, with a depth image), or None."""
    if objects is None:
        return None
    if camera_kind == "tool_points":
        raise DatasetError(f"{bag.path}: --object-from-cloud estimates the object from the scene's camera frames "
                           f"({names['points']} or {names['depth']}), and this bag's camera is the tool's cloud "
                           f"{names['tool_points']}; name the scene camera with --topic points=NAME or --topic "
                           "depth=NAME, or import without --object-from-cloud")
    mask = names["object_mask"]
    if mask in bag.topics and bag.topics[mask] != KINDS["object_mask"].msgtype:
        raise DatasetError(f"{bag.path}: topic {mask} is {bag.topics[mask]}, but the import reads object_mask as "
                           f"{KINDS['object_mask'].msgtype}; point --topic object_mask=NAME at a mask image")
    return mask if camera_kind == "depth" and mask in bag.topics else None


class _ObjectSteps:
    """The object of a bag's steps from the camera (``ObjectTrack``, reset per trial), and its counts over the
    bag for the summary line."""

    def __init__(self, objects: ObjectFromCloud, segmentation: str):
        self.objects, self.segmentation, self.track = objects, segmentation, ObjectTrack()
        self.steps, self.fresh, self.flags = 0, 0, {}

    def add_trial(self) -> None:
        """Count the trial ``track`` has followed."""
        self.steps += self.track.steps
        self.fresh += self.track.fresh_steps
        for flag, n in self.track.flags.items():
            self.flags[flag] = self.flags.get(flag, 0) + n

    def line(self) -> str:
        flags = ", ".join(f"{n} {flag}" for flag, n in sorted(self.flags.items()))
        return (f"object from the camera ({self.objects.estimator}, segmented by the {self.segmentation}): "
                f"{self.fresh} of {self.steps} steps estimated"
                + (f", the others flagged and carrying the last estimate ({flags})" if flags else ""))


def _exported_metadata(bag: Bag, payload, summary: BagSummary) -> dict:
    """The episode metadata a hingelab export recorded (``/hingelab/episode``); {} if it is not a JSON object."""
    text = bag.deserialize(payload, "std_msgs/msg/String").data
    try:
        metadata = json.loads(text)
    except ValueError:
        metadata = None
    if not isinstance(metadata, dict):
        summary.notes.append("a /hingelab/episode message is not a JSON object; its trial keeps the trial index "
                             "as its seed")
        return {}
    return metadata


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
                   objects: Stream | None, tf: TfTree, state, summary: BagSummary, bar, exported: dict,
                   from_cloud: _ObjectSteps | None = None):
    n_grid = (trial.end_ns - trial.start_ns) // STEP_NS + 1
    if n_grid < 1:
        summary.notes.append(f"trial {index} ends before it starts; skipped")
        return None
    state.reset()
    perception, used = {}, {k: v for k, v in names.items() if v in bag.topics and k != "object_mask"}
    if from_cloud is not None:
        from_cloud.track.reset()
        perception = {KEY_OBJECT_PERCEPTION: from_cloud.objects.estimator,
                      "ros2_object_segmentation": from_cloud.segmentation}
        if from_cloud.segmentation == "mask":
            used["object_mask"] = names["object_mask"]
    action_dim = action.dim if action.stream is not None else 5
    has_action = action.stream is not None
    seed = exported.get("seed")
    seed = seed if isinstance(seed, int) and not isinstance(seed, bool) else index
    kept = {"ros2_exported_episode_id": str(exported["episode_id"])} if exported.get("episode_id") else {}
    writer = EpisodeWriter(out, source=SOURCE, task=TASK, object=str(exported.get("object") or ""), seed=seed,
                           attempt=trial.attempts, log_time_origin_ns=int(trial.start_ns),  # the rig's clock
                           action_level="high" if action_dim == 5 else ("low" if action_dim == 9 else ""),
                           extra_metadata={
                               "ros2_bag": bag.name, "ros2_bag_path": str(bag.path.resolve()),
                               "ros2_bag_topics": sorted(bag.topics), "ros2_bag_start_ns": int(bag.start_ns),
                               "ros2_bag_end_ns": int(bag.end_ns), "ros2_trial_index": index,
                               "ros2_trial_start_ns": int(trial.start_ns), "ros2_trial_end_ns": int(trial.end_ns),
                               "ros2_trial_closed_by": trial.closed_by,
                               "ros2_topics_used": [f"{k}={v}" for k, v in sorted(used.items())],
                               **kept, **perception})
    skipped = 0
    with writer:
        for k in range(n_grid):
            bar.update(1)
            t = trial.start_ns + k * STEP_NS
            hand = joints.hand_at(t)
            cam = camera.latest(t)
            if hand is None or cam is None:
                if writer.length == 0:
                    skipped += 1
                    continue
                raise AssertionError("a stream lost its sample mid-episode")  # latest-at-or-before only grows
            q, qdot, hand_stamp = hand
            arm, arm_stamp = joints.arm_at(t)
            cam_index, points, n_distinct, tf_stamp = cam
            cam_stamp = int(camera.stamps[cam_index])
            sample = state.update(points[None], n_distinct=n_distinct)
            values, action_stamp = action.at(t)
            act = np.full(action_dim, np.nan) if values is None else values
            obj, obj_stamp = _object_position(bag, objects, tf, t)
            recorded_object = obj  # the bag's object pose, if any: beside the camera's estimate, as its reference
            if from_cloud is not None:
                found = from_cloud.track.step(camera.object_at(t), from_cloud.objects.hand_in_world(arm))
                obj, obj_stamp = found.position, found.stamp
            position, rotation = sample.position[0], sample.rotation[0]
            success_now = trial.success_ns is not None and trial.success_ns <= t
            attempt_now = 1 + sum(1 for et, text in trial.events if et <= t and text.strip().lower() == "attempt")
            info = {"age_joints_s": _age(t, hand_stamp), "age_arm_joints_s": _age(t, arm_stamp),
                    "age_cloud_s": _age(t, cam_stamp),
                    "age_tf_s": 0.0 if tf_stamp is None else _age(t, tf_stamp),
                    "age_action_s": _age(t, action_stamp), "age_object_s": _age(t, obj_stamp),
                    "cloud_points": float(n_distinct), "is_success": float(success_now), "attempt": float(attempt_now),
                    **{name: float(v) for name, v in zip(ARM_JOINT_NAMES, arm)}}
            last = k == n_grid - 1
            observation = np.concatenate([position, sample.euler_xyz[0], sample.z_smoothed[0], obj, NAN3])
            writer.write_step(
                (t - trial.start_ns) / 1e9, points_hand=points, tool_pose_hand=(position, M.quaternion_xyzw(rotation)),
                joint_position=q, joint_velocity=qdot, latent_z=sample.z[0], latent_z_smoothed=sample.z_smoothed[0],
                action=act if has_action else None,
                object_position_hand=obj if objects is not None or from_cloud is not None else None,
                transition=dict(observation=observation, action=act, reward=np.nan,
                                terminated=last and trial.closed_by == "end",
                                truncated=last and trial.closed_by != "end", info=info))
            if from_cloud is not None:
                writer.write_object_estimate(
                    (t - trial.start_ns) / 1e9, estimator=from_cloud.objects.estimator, position=found.position,
                    extent=found.extent, n_points=found.n_points, fresh=found.fresh, flag=found.flag,
                    true_position=recorded_object if np.isfinite(recorded_object).all() else None,
                    points=found.points)
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
    if from_cloud is not None:
        from_cloud.add_trial()
        _note_missing_object(summary, index, from_cloud.track)
    summary.steps += writer.length
    return writer.path


def _note_missing_object(summary: BagSummary, index: int, track: ObjectTrack) -> None:
    """The trial's steps before its first object estimate (its /object/position is NaN there): said, not hidden."""
    if not track.before_first:
        return
    where = ("at any of its" if track.before_first == track.steps else "at the first") + f" {track.before_first}"
    summary.notes.append(f"trial {index}: no object estimate {where} steps (first flag: {track.first_flag}); its "
                         "/object/position is NaN there, and train high leaves such an episode out")


__all__ = ["BagSummary", "import_bags", "import_bag", "near_crop_box", "STEP_NS", "AGE_STREAMS", "SOURCE", "TASK"]
