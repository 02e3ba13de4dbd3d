"""Episodes -> ROS 2 bags: each episode a rosbag2 folder with MCAP storage, readable by rosbags and ROS 2 tools.

``export_ros2(dataset, out)`` writes ``OUT/<episode_id>/`` (``metadata.yaml`` + ``<episode_id>.mcap``)
per episode (an ``episode_id`` that is not a plain file name is refused: ``hingelab.safe_names``),
with the standard types (definitions stored in the bag, as ``ros2 bag record`` does):

| topic | type | from the episode |
|---|---|---|
| ``/joint_states`` | sensor_msgs/msg/JointState | ``/hand/joints`` under the platform names (``svh_*``), and
  arm_joint_1..6 when the steps carry them (imported episodes) |
| ``/tool/points`` | sensor_msgs/msg/PointCloud2 | the 256-point tool cloud, x, y, z float32, frame ``hand_base`` |
| ``/tf`` | tf2_msgs/msg/TFMessage | ``hand_base`` -> ``tool``, the registered tool pose |
| ``/trial/event`` | std_msgs/msg/String | ``start`` at the first step, ``attempt`` where the step's attempt grows,
  ``success`` at the first successful step (or the last), ``failure:<reason>`` at the last step of a failed one,
  ``end`` at the last step |
| ``/hingelab/action`` | std_msgs/msg/Float64MultiArray | ``/action`` values |
| ``/object/pose`` | geometry_msgs/msg/PoseStamped | ``/object/position``, frame ``hand_base`` (identity orientation) |

Bag time = the episode's log time plus ``ros2_trial_start_ns`` for imported episodes (the
rig's own clock back), 0 otherwise; every message is stamped (header and log time) at its step.
``hingelab datasets import-ros2 OUT/<id> --topic points=/tool/points`` imports such a bag back to
the same steps (the cloud already in ``hand_base`` goes through the pipeline again).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export import register_exporter
from hingelab.episodes.export_output import ExportResult, atomic_folder
from hingelab.errors import ConfigError
from hingelab.ros2.rig_bag import _header, _tf, point_cloud2
from hingelab.ros2.topics import ARM_JOINT_NAMES, HAND_JOINTS, KINDS
from hingelab.safe_names import safe_file_name

TOOL_POINTS_TOPIC = "/tool/points"


def _events(episode, times: np.ndarray) -> list[tuple[int, str]]:
    step = episode.topics.get(S.TOPIC_STEP, {})
    meta = episode.metadata
    events = [(int(times[0]), "start")]
    attempt = step.get("info.attempt")
    if attempt is not None and len(attempt) == len(times):
        for k in np.nonzero(np.diff(attempt) > 0)[0] + 1:
            events.extend([(int(times[k]), "attempt")] * int(attempt[k] - attempt[k - 1]))
    if meta.get(S.KEY_SUCCESS):
        flags = step.get("info.is_success")
        hit = np.nonzero(flags > 0.5)[0] if flags is not None and len(flags) == len(times) else []
        events.append((int(times[hit[0]] if len(hit) else times[-1]), "success"))
    else:
        events.append((int(times[-1]), "failure:" + str(meta.get(S.KEY_FAILURE_REASON) or "failure")))
    events.append((int(times[-1]), "end"))
    return events


def export_episode(episode, folder: Path) -> int:
    """Write one episode as the rosbag2 folder ``folder``; returns the number of messages written."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    base = int(episode.metadata.get("ros2_trial_start_ns", 0) or 0)
    topics = episode.topics
    messages = []  # (t ns, order, topic, message)

    def add(t, topic, msg):
        messages.append((int(t), len(messages), topic, msg))

    step = topics.get(S.TOPIC_STEP, {})
    if S.TOPIC_JOINTS in topics:
        joints = topics[S.TOPIC_JOINTS]
        arm = [step.get(f"info.{name}") for name in ARM_JOINT_NAMES]
        with_arm = all(a is not None and len(a) == len(joints["log_time_ns"]) for a in arm)
        for k, t in enumerate(joints["log_time_ns"]):
            names, position = list(HAND_JOINTS), list(np.asarray(joints["position"][k], float))
            velocity = list(np.asarray(joints["velocity"][k], float))
            if with_arm and not np.isnan([a[k] for a in arm]).any():
                names += list(ARM_JOINT_NAMES)
                position += [float(a[k]) for a in arm]
                velocity += [np.nan] * len(ARM_JOINT_NAMES)
            add(base + t, KINDS["joints"].default, T["sensor_msgs/msg/JointState"](
                header=_header(ts, base + t), name=names, position=np.array(position), velocity=np.array(velocity),
                effort=np.zeros(0)))
    if S.TOPIC_POINTS in topics:
        cloud = topics[S.TOPIC_POINTS]
        for k, t in enumerate(cloud["log_time_ns"]):
            add(base + t, TOOL_POINTS_TOPIC, point_cloud2(ts, base + t, S.FRAME_HAND, cloud["points"][k]))
    if S.TOPIC_TOOL_POSE in topics:
        pose = topics[S.TOPIC_TOOL_POSE]
        for k, t in enumerate(pose["log_time_ns"]):
            rot = Rotation.from_quat(np.asarray(pose["orientation"][k], float)).as_matrix()
            add(base + t, KINDS["tf"].default, T["tf2_msgs/msg/TFMessage"](
                transforms=[_tf(ts, base + t, S.FRAME_HAND, S.FRAME_TOOL, rot,
                                np.asarray(pose["position"][k], float))]))
    if S.TOPIC_ACTION in topics:
        action = topics[S.TOPIC_ACTION]
        for k, t in enumerate(action["log_time_ns"]):
            add(base + t, KINDS["action"].default, T["std_msgs/msg/Float64MultiArray"](
                layout=T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
                data=np.asarray(action["values"][k], float)))
    if S.TOPIC_OBJECT in topics:
        obj = topics[S.TOPIC_OBJECT]
        for k, t in enumerate(obj["log_time_ns"]):
            p = np.asarray(obj["position"][k], float)
            add(base + t, KINDS["object"].default, T["geometry_msgs/msg/PoseStamped"](
                header=_header(ts, base + t, S.FRAME_HAND),
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))))
    step_times = step.get("log_time_ns")
    if step_times is None or not len(step_times):
        step_times = next((f["log_time_ns"] for f in topics.values() if len(f.get("log_time_ns", []))), None)
    if step_times is not None and len(step_times):
        for t, text in _events(episode, np.asarray(step_times) + base):
            add(t, KINDS["events"].default, T["std_msgs/msg/String"](data=text))
    messages.sort(key=lambda m: (m[0], m[1]))
    connections = {}
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for t, _, topic, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(connections[topic], t, ts.serialize_cdr(msg, msg.__msgtype__))
    return len(messages)


def export_ros2(dataset, out, progress: bool = False) -> ExportResult:
    """Every episode of ``dataset`` (a ``Dataset``) as ``OUT/<episode_id>/``, a rosbag2 folder (MCAP storage)."""
    out = Path(out)
    paths = dataset.paths()
    result = ExportResult("ros2", out, 0, 0, load="rosbags.highlevel.AnyReader([Path('OUT/<episode_id>')]), "
                                                  "ros2 bag info OUT/<episode_id>, or hingelab datasets import-ros2 "
                                                  "OUT/<episode_id> --topic points=/tool/points --out DIR")
    messages = 0
    with atomic_folder(out) as tmp:
        for path in tqdm(paths, desc="export ros2", unit="episode", disable=not progress):
            episode = dataset.read_checked(path)
            if episode is None:
                result.skipped.setdefault("unreadable", []).append(path.name)
                continue
            if not any(len(f.get("log_time_ns", [])) for f in episode.topics.values()):
                result.skipped.setdefault("no messages", []).append(path.name)
                continue
            episode_id = episode.metadata.get(S.KEY_EPISODE_ID)
            name = safe_file_name(path.stem if episode_id is None else str(episode_id), "episode_id", path)
            if (tmp / name).exists():
                raise DatasetError(f"{path}: episode_id {name!r} is also the id of an episode exported before it; "
                                   "a ros2 export names each bag folder by its episode's id, so ids must differ")
            messages += export_episode(episode, tmp / name)
            result.episodes += 1
            result.frames += int(episode.length)
    result.notes.append(f"{messages} messages in {result.episodes} rosbag2 folders (MCAP storage)")
    return result


def _export(dataset, out, dataset_id=None, progress=False) -> ExportResult:
    if dataset_id is not None:
        raise ConfigError("--dataset-id names a Minari dataset; a ros2 export is one bag folder per episode")
    return export_ros2(dataset, out, progress=progress)


register_exporter("ros2", _export)

__all__ = ["export_ros2", "export_episode", "TOOL_POINTS_TOPIC"]
