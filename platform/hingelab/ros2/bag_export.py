"""Episodes -> ROS 2 bags: each episode a rosbag2 folder with MCAP storage, readable by rosbags and ROS 2 tools.

``export_ros2(dataset, out)`` writes ``OUT/<episode_id>/`` (``metadata.yaml`` + ``<episode_id>.mcap``)
per episode (an ``episode_id`` that is not a plain file name is refused: ``hingelab.safe_names``),
with every topic the episode has (definitions stored in the bag, as ``ros2 bag record`` does):

| topic | type | from the episode |
|---|---|---|
| ``/joint_states`` | sensor_msgs/msg/JointState | ``/hand/joints`` under the platform names (``svh_*``) with
  ``/arm/joints`` (arm_joint_1..6) in the same message when logged with it; an imported episode's arm joints
  (its steps' ``arm_joint_*`` infos) in a message of their own, without velocities |
| ``/tool/points`` | sensor_msgs/msg/PointCloud2 | the 256-point tool cloud, x, y, z float32, frame ``hand_base`` |
| ``/tf`` | tf2_msgs/msg/TFMessage | ``hand_base`` -> ``tool`` (the registered tool pose); ``world`` -> ``hand_base``
  (the arm's forward kinematics of the recorded arm joints, ``sim.arm_kinematics``) when the episode has them |
| ``/tf_static`` | tf2_msgs/msg/TFMessage | the depth camera's fixed mount: ``hand_base`` -> ``camera_depth_optical``
  when its pose in the world (through the arm's kinematics) never changes (1 mm, 1 mrad), else ``hand_base`` ->
  ``camera_depth_optical`` when its pose in the hand never changes; a camera that moves in both goes on ``/tf``
  from ``hand_base`` |
| ``/camera/depth/image_raw`` | sensor_msgs/msg/Image | ``/camera/depth``: 16UC1 millimetres as recorded |
| ``/camera/depth/camera_info`` | sensor_msgs/msg/CameraInfo | ``/camera/calibration``, with every depth image |
| ``/trial/event`` | std_msgs/msg/String | ``start`` at the first step, ``attempt`` where the step's attempt grows,
  ``success`` at the first successful step (or the last), ``failure:<reason>`` at the last step of a failed one,
  ``end`` at the last step |
| ``/hingelab/action`` | std_msgs/msg/Float64MultiArray | ``/action``; ``layout.dim[0].label`` names the values
  (``episode_messages.action_names``: z_goal_0,z_goal_1,hand_velocity_x,... for ToolPick-v0) |
| ``/object/pose``, ``/target/pose`` | geometry_msgs/msg/PoseStamped | ``/object/position``, ``/target/position``,
  frame ``hand_base`` (identity orientation) |
| ``/object/points`` | sensor_msgs/msg/PointCloud2 | the object's visible points, frame ``hand_base`` |
| ``/hingelab/episode`` | std_msgs/msg/String | the episode's metadata (seed, object, outcome, ...) as JSON |
| ``/hingelab/<topic>`` | hingelab_msgs/msg/<Name> | every other topic (``/step``, ``/tool/latent``, ``/goal``,
  ``/reward/terms``, ``/sim/privileged``, ``/object/estimate``): a message type with the topic's named fields
  (``episode_messages``) |

Standard-typed topics hold no NaN: a step without a sample (an imported episode's action or object before its
first message, a joint without a reading) is left out, as the rig left it out; hingelab_msgs fields keep the
episode's values, NaN included (a real trial's reward).

Bag time = the episode's time plus its wall-clock start, ``log_time_origin_ns`` (schema 6; for imported episodes
``ros2_trial_start_ns``, the rig's own clock back; 0 for files older than schema 6); every message is stamped
(header and log time) at its step.
``hingelab datasets import-ros2 OUT/<id>`` imports such a bag back with no ``--topic`` flag: it takes
``/tool/points`` as the tool cloud (``topics.py``, kind ``tool_points``) and the seed and object from
``/hingelab/episode``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from hingelab.episodes import schemas as S
from hingelab.episodes.camera_topics import read_camera
from hingelab.episodes.codec import decode_point_cloud
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export import register_exporter
from hingelab.episodes.export_output import ExportResult, atomic_folder
from hingelab.episodes.reader import EpisodeFile
from hingelab.errors import ConfigError
from hingelab.ros2.episode_messages import (
    EPISODE_TOPIC,
    LABELLED_PREFIX,
    LabelledType,
    action_message,
    action_names,
    episode_message,
)
from hingelab.ros2.rig_bag import _header, _tf, point_cloud2
from hingelab.ros2.topics import ARM_JOINT_NAMES, HAND_JOINTS, KINDS
from hingelab.safe_names import safe_file_name
from hingelab.sim.arm_kinematics import default_kinematics

TOOL_POINTS_TOPIC = KINDS["tool_points"].default
WORLD_FRAME = "world"  # the arm's base frame, as in the simulator and the rig's TF tree
FIXED_M, FIXED_RAD = 1e-3, 1e-3  # a camera pose that moves less than this over an episode is a fixed mount
# episode topics that go to standard types (the rest to hingelab_msgs); /tf is the viewer copy of /tool/pose
STANDARD = {S.TOPIC_JOINTS, S.TOPIC_ARM_JOINTS, S.TOPIC_POINTS, S.TOPIC_TOOL_POSE, S.TOPIC_TF, S.TOPIC_ACTION,
            S.TOPIC_OBJECT, S.TOPIC_TARGET, S.TOPIC_OBJECT_POINTS, S.TOPIC_COLUMNS, *S.CAMERA_TOPICS}
POSE_TOPICS = {S.TOPIC_OBJECT: KINDS["object"].default, S.TOPIC_TARGET: "/target/pose"}
DEPTH_TOPIC, CAMERA_INFO_TOPIC = KINDS["depth"].default, KINDS["camera_info"].default


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


def _finite(*values) -> bool:
    return all(np.isfinite(np.asarray(v, float)).all() for v in values)


def _arm_rows(episode) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """(log times (N,), arm q (N, 6), q-dot (N, 6) or None) from /arm/joints, else the steps' arm_joint_* infos."""
    arm = episode.topics.get(S.TOPIC_ARM_JOINTS)
    if arm is not None and len(arm["log_time_ns"]):
        return np.asarray(arm["log_time_ns"]), np.asarray(arm["position"], float), np.asarray(arm["velocity"], float)
    step = episode.topics.get(S.TOPIC_STEP, {})
    columns = [step.get(f"info.{name}") for name in ARM_JOINT_NAMES]
    if any(c is None for c in columns):
        return None
    return np.asarray(step["log_time_ns"]), np.stack(columns, axis=1).astype(float), None


def _fixed(rot: np.ndarray, pos: np.ndarray) -> bool:
    """Poses (K, 3, 3), (K, 3) all within FIXED_M and FIXED_RAD of the first."""
    angle = np.linalg.norm(Rotation.from_matrix(np.einsum("kji,jl->kil", rot, rot[0])).as_rotvec(), axis=1)
    return bool(np.abs(pos - pos[0]).max() <= FIXED_M and angle.max() <= FIXED_RAD)


def _camera_mount(camera, arm, hand_world) -> tuple[str | None, int | None]:
    """Where the camera's fixed mount is: (WORLD_FRAME, arm row of the first frame) when it does not move in the
    world (a rig's camera on a tripod: checked first, since over a short episode the hand may barely move either),
    else ("hand_base", None) when it does not move in the hand, else (None, None)."""
    rows = None if arm is None else np.searchsorted(arm[0], camera.log_time_ns, side="right") - 1
    if rows is not None and (rows >= 0).all() and np.isfinite(hand_world[1][rows]).all():
        rot_w, pos_w = hand_world[0][rows], hand_world[1][rows]
        if _fixed(np.einsum("kij,kjl->kil", rot_w, camera.rotation),
                  np.einsum("kij,kj->ki", rot_w, camera.position) + pos_w):
            return WORLD_FRAME, int(rows[0])
    if _fixed(camera.rotation, camera.position):
        return S.FRAME_HAND, None
    return None, None


def export_episode(episode, folder: Path) -> int:
    """Write one episode as the rosbag2 folder ``folder``; returns the number of messages written."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    # the episode's wall-clock start (schema 6; an imported episode's is its trial's start on the rig's clock),
    # so that a bag of a simulated episode is not dated 1970; 0 for older files, which have none
    base = int(episode.metadata.get(S.KEY_LOG_TIME_ORIGIN) or episode.metadata.get("ros2_trial_start_ns") or 0)
    topics = episode.topics
    messages = []  # (t ns, order, topic, message)

    def add(t, topic, msg):
        messages.append((int(t), len(messages), topic, msg))

    def header(t, frame=""):
        return _header(ts, base + t, frame)

    step = topics.get(S.TOPIC_STEP, {})
    arm = _arm_rows(episode)
    hand_world = None
    if arm is not None:
        known = np.isfinite(arm[1]).all(axis=1)
        rot, pos = np.full((len(arm[1]), 3, 3), np.nan), np.full((len(arm[1]), 3), np.nan)
        if known.any():
            rot[known], pos[known] = default_kinematics().hand_poses(arm[1][known])
        hand_world = (rot, pos)
        for k, t in enumerate(arm[0]):
            if known[k]:
                add(base + t, KINDS["tf"].default, T["tf2_msgs/msg/TFMessage"](transforms=[
                    _tf(ts, base + t, WORLD_FRAME, S.FRAME_HAND, rot[k], pos[k])]))
    arm_with_hand = set()  # arm rows sent inside the hand's JointState
    if S.TOPIC_JOINTS in topics:
        joints = topics[S.TOPIC_JOINTS]
        arm_row = {int(t): k for k, t in enumerate(arm[0])} if arm is not None and arm[2] is not None else {}
        for k, t in enumerate(joints["log_time_ns"]):
            names = list(HAND_JOINTS)
            position, velocity = np.asarray(joints["position"][k], float), np.asarray(joints["velocity"][k], float)
            j = arm_row.get(int(t))
            if j is not None and _finite(arm[1][j], arm[2][j]):
                names += list(ARM_JOINT_NAMES)
                position, velocity = np.concatenate([position, arm[1][j]]), np.concatenate([velocity, arm[2][j]])
                arm_with_hand.add(j)
            if not _finite(position):
                continue
            add(base + t, KINDS["joints"].default, T["sensor_msgs/msg/JointState"](
                header=header(t), name=names, position=position,
                velocity=velocity if _finite(velocity) else np.zeros(0), effort=np.zeros(0)))
    if arm is not None:  # arm joints not sent with the hand's: a message of their own (another driver, as on a rig)
        for k, t in enumerate(arm[0]):
            velocity = arm[2][k] if arm[2] is not None else np.zeros(0)
            if k not in arm_with_hand and _finite(arm[1][k]):
                add(base + t, KINDS["joints"].default, T["sensor_msgs/msg/JointState"](
                    header=header(t), name=list(ARM_JOINT_NAMES), position=arm[1][k],
                    velocity=velocity if _finite(velocity) else np.zeros(0), effort=np.zeros(0)))
    if S.TOPIC_POINTS in topics:
        cloud = topics[S.TOPIC_POINTS]
        for k, t in enumerate(cloud["log_time_ns"]):
            if _finite(cloud["points"][k]):
                add(base + t, TOOL_POINTS_TOPIC, point_cloud2(ts, base + t, S.FRAME_HAND, cloud["points"][k]))
    if S.TOPIC_TOOL_POSE in topics:
        pose = topics[S.TOPIC_TOOL_POSE]
        for k, t in enumerate(pose["log_time_ns"]):
            if _finite(pose["orientation"][k], pose["position"][k]):
                rot = Rotation.from_quat(np.asarray(pose["orientation"][k], float)).as_matrix()
                add(base + t, KINDS["tf"].default, T["tf2_msgs/msg/TFMessage"](
                    transforms=[_tf(ts, base + t, S.FRAME_HAND, S.FRAME_TOOL, rot,
                                    np.asarray(pose["position"][k], float))]))
    if S.TOPIC_ACTION in topics:
        action = topics[S.TOPIC_ACTION]
        names = action_names(np.asarray(action["values"]).shape[1])
        for k, t in enumerate(action["log_time_ns"]):
            if _finite(action["values"][k]):
                add(base + t, KINDS["action"].default, action_message(ts, action["values"][k], names))
    for source, topic in POSE_TOPICS.items():
        for k, t in enumerate(topics.get(source, {}).get("log_time_ns", [])):
            p = np.asarray(topics[source]["position"][k], float)
            if _finite(p):
                add(base + t, topic, T["geometry_msgs/msg/PoseStamped"](
                    header=header(t, S.FRAME_HAND), pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))))
    _add_camera(episode, ts, base, add, arm, hand_world)
    _add_object_points(episode, ts, base, add)
    for topic, fields in topics.items():
        if topic in STANDARD or not len(fields.get("log_time_ns", [])):
            continue
        labelled = LabelledType(ts, topic, fields)
        for k, t in enumerate(fields["log_time_ns"]):
            add(base + t, LABELLED_PREFIX + topic, labelled.message(header(t), fields, k))
    step_times = step.get("log_time_ns")
    if step_times is None or not len(step_times):
        step_times = next((f["log_time_ns"] for f in topics.values() if len(f.get("log_time_ns", []))), None)
    if step_times is not None and len(step_times):
        for t, text in _events(episode, np.asarray(step_times) + base):
            add(t, KINDS["events"].default, T["std_msgs/msg/String"](data=text))
    if messages:
        add(min(m[0] for m in messages), EPISODE_TOPIC, episode_message(ts, episode.metadata))
    messages.sort(key=lambda m: (m[0], m[1]))
    connections = {}
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for t, _, topic, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(connections[topic], t, ts.serialize_cdr(msg, msg.__msgtype__))
    return len(messages)


def _add_camera(episode, ts, base: int, add, arm, hand_world) -> None:
    """Depth images, their camera_info and the camera's pose (``/tf_static`` for a fixed mount)."""
    camera = read_camera(episode.path)
    if camera is None or not len(camera.log_time_ns):
        return
    T = ts.types
    k = camera.intrinsics
    mount, row = _camera_mount(camera, arm, hand_world)
    if mount == S.FRAME_HAND:
        static = [_tf(ts, base + int(camera.log_time_ns[0]), S.FRAME_HAND, S.FRAME_CAMERA, camera.rotation[0],
                      camera.position[0])]
    elif mount == WORLD_FRAME:
        rot_w, pos_w = hand_world[0][row], hand_world[1][row]
        static = [_tf(ts, base + int(camera.log_time_ns[0]), WORLD_FRAME, S.FRAME_CAMERA, rot_w @ camera.rotation[0],
                      rot_w @ camera.position[0] + pos_w)]
    if mount is not None:
        add(base + int(camera.log_time_ns[0]), KINDS["tf_static"].default,
            T["tf2_msgs/msg/TFMessage"](transforms=static))
    for j, t in enumerate(camera.log_time_ns):
        t = int(t)
        if mount is None:
            add(base + t, KINDS["tf"].default, T["tf2_msgs/msg/TFMessage"](transforms=[
                _tf(ts, base + t, S.FRAME_HAND, S.FRAME_CAMERA, camera.rotation[j], camera.position[j])]))
        mm = np.clip(np.rint(camera.depth[j].astype(np.float64) * 1000.0), 0, 65535).astype("<u2")
        height, width = mm.shape
        add(base + t, DEPTH_TOPIC, T["sensor_msgs/msg/Image"](
            header=_header(ts, base + t, S.FRAME_CAMERA), height=height, width=width, encoding="16UC1",
            is_bigendian=0, step=2 * width, data=mm.view(np.uint8).ravel()))
        if k is not None:
            add(base + t, CAMERA_INFO_TOPIC, T["sensor_msgs/msg/CameraInfo"](
                header=_header(ts, base + t, S.FRAME_CAMERA), height=k.height, width=k.width,
                distortion_model="plumb_bob", d=np.zeros(5), k=np.array([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1], float),
                r=np.eye(3).ravel(), p=np.array([k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0], float),
                binning_x=0, binning_y=0, roi=T["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)))


def _add_object_points(episode, ts, base: int, add) -> None:
    """The object's visible points (their number varies by frame), read message by message."""
    with EpisodeFile(episode.path) as episode_file:
        if S.TOPIC_OBJECT_POINTS not in episode_file.channels:
            return
        for _, t, message in episode_file.iter_messages([S.TOPIC_OBJECT_POINTS]):
            points = decode_point_cloud(message)
            points = points[np.isfinite(points).all(axis=1)]
            add(base + t, "/object/points", point_cloud2(ts, base + t, S.FRAME_HAND, points))


def export_ros2(dataset, out, progress: bool = False) -> ExportResult:
    """Every episode of ``dataset`` (a ``Dataset``) as ``OUT/<episode_id>/``, a rosbag2 folder (MCAP storage)."""
    out = Path(out)
    paths = dataset.paths()
    result = ExportResult("ros2", out, 0, 0, load="rosbags.highlevel.AnyReader([Path('OUT/<episode_id>')]), "
                                                  "ros2 bag info OUT/<episode_id>, or hingelab datasets import-ros2 "
                                                  "OUT/<episode_id> --out DIR")
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

__all__ = ["export_ros2", "export_episode", "TOOL_POINTS_TOPIC", "WORLD_FRAME"]
