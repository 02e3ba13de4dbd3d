"""A synthetic rig bag: what ``ros2 bag record`` on the real rig writes, for tests, the benchmark and demos.

``write_rig_bag(path, RigBagSpec(...))`` writes a rosbag2 folder (MCAP or sqlite3 storage) with
the rig's topics at the rig's rates, through ``rosbags``' writer:

- ``/joint_states`` (100 Hz): arm_joint_1..6 and the hand's 9 channels (platform names), slow sines, in
  one message or (``split_joint_drivers``) one from each driver;
- ``/camera/depth/points`` (30 Hz), PointCloud2 in ``camera_depth_optical_frame``: the tweezer
  sampled by ``CloudSynthesizer`` at the nominal in-hand pose (its opening swinging), expressed in
  the camera frame, plus a table plane that the crop box removes; or, with ``depth_images``,
  ``/camera/depth/image_raw`` (32FC1 metres) and ``/camera/depth/camera_info`` rendered from it;
- ``/tf_static``: world -> arm_base, world -> camera_link -> camera_depth_optical_frame,
  flange -> hand_base; ``/tf`` (100 Hz): arm_base -> flange, the arm moving slowly;
- ``/trial/event``: per trial ``start``, optional ``attempt``/``failure``, ``success`` or
  ``failure``, ``end``; ``/hingelab/action`` (20 Hz, 5 values); ``/object/pose`` (30 Hz, world).

Header stamps are capture times; log times come later by each driver's latency (camera 30 ms,
joints 2 ms), as on a real rig.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from hingelab.ros2.topics import ARM_JOINT_NAMES, HAND_JOINTS

T0_NS = 1_733_000_000 * 1_000_000_000  # bag time of the first message (a plausible ROS time)
CAMERA_OPTICAL = "camera_depth_optical_frame"
# The camera in the world: 0.6 m in front of the hand, looking back at it (optical z toward the hand).
# Optical axes as columns in the world: x right (+y), y down (-z), z forward (-x).
CAMERA_IN_WORLD = (np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.array([0.9, 0.0, 0.45]))
FLANGE_IN_ARM = np.array([0.3, 0.0, 0.4])
HAND_IN_FLANGE = (np.eye(3), np.array([0.0, 0.0, 0.05]))


@dataclass
class RigTrial:
    duration_s: float = 1.2
    outcome: str = "success"  # "success", "failure", "abort"
    attempts: int = 1
    end_event: bool = True


@dataclass
class RigBagSpec:
    trials: list = field(default_factory=lambda: [RigTrial(), RigTrial(outcome="failure"),
                                                  RigTrial(attempts=2)])
    gap_s: float = 0.5  # between trials, and before the first one
    storage: str = "mcap"  # or "sqlite3"
    depth_images: bool = False
    depth_size: tuple = (320, 288)  # (width, height) of the depth images
    scene_points: int = 1500
    tool_points: int | None = None  # of the scene's points on the tweezer (None: half of them); the rest table
    joint_hz: float = 100.0
    camera_hz: float = 30.0
    action: bool = True
    object_pose: bool = True
    non_monotonic_joints: int = 0  # swap this many pairs of consecutive joint stamps
    blind_frames: tuple = ()  # camera frames (indices) that see only the table: the tool out of view
    split_joint_drivers: bool = False  # the arm's and the hand's drivers each publish their own JointState
    hand_joint_names: tuple = HAND_JOINTS  # the names the hand's driver gives its 9 channels
    seed: int = 0
    topics: dict = field(default_factory=dict)  # kind -> another topic name


def _tf(ts, stamp_ns, parent, child, rot, pos):
    T = ts.types
    q = Rotation.from_matrix(rot).as_quat()
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, stamp_ns, parent), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=pos[0], y=pos[1], z=pos[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))


def _header(ts, stamp_ns, frame_id=""):
    T = ts.types
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000),
                                                                          nanosec=int(stamp_ns % 1_000_000_000)),
                                    frame_id=frame_id)


def point_cloud2(ts, stamp_ns, frame_id, points):
    T = ts.types
    points = np.ascontiguousarray(points, dtype="<f4")
    fields = [T["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    return T["sensor_msgs/msg/PointCloud2"](header=_header(ts, stamp_ns, frame_id), height=1, width=len(points),
                                            fields=fields, is_bigendian=False, point_step=12,
                                            row_step=12 * len(points), data=points.view(np.uint8).ravel(),
                                            is_dense=True)


def flange_pose(t_s: float):
    """arm_base -> flange: the arm sways slowly (a few cm, a few degrees)."""
    rot = Rotation.from_euler("z", 0.05 * np.sin(0.7 * t_s)).as_matrix()
    return rot, FLANGE_IN_ARM + np.array([0.02 * np.sin(0.5 * t_s), 0.01 * np.cos(0.4 * t_s), 0.0])


def hand_in_world(t_s: float):
    rf, pf = flange_pose(t_s)
    rh, ph = HAND_IN_FLANGE
    return rf @ rh, rf @ ph + pf


def camera_in_hand(t_s: float):
    rw, pw = hand_in_world(t_s)
    rc, pc = CAMERA_IN_WORLD
    return rw.T @ rc, rw.T @ (pc - pw)


def write_rig_bag(path, spec: RigBagSpec = RigBagSpec()) -> dict:
    """Write the bag; returns what a test checks against: per trial its start/end (ns) and outcome."""
    # perception loads mujoco, trimesh and numba (about 2 s); bag_export uses the helpers here without them
    from hingelab.perception.clouds import CloudRealism, CloudSynthesizer
    from hingelab.perception.synthetic_dataset import nominal_tool_pose

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    rng = np.random.default_rng(spec.seed)
    synth = CloudSynthesizer(realism=CloudRealism(noise_std_m=0.0005, removal_fraction=0.0, max_angle_rad=0.0,
                                                  max_offset_m=0.0), seed=spec.seed,
                             n_points=max(16, spec.tool_points or spec.scene_points // 2))
    synth.new_episode(spec.seed)
    tool_rot, tool_pos = nominal_tool_pose()
    names = {"joints": "/joint_states", "points": "/camera/depth/points", "depth": "/camera/depth/image_raw",
             "camera_info": "/camera/depth/camera_info", "tf": "/tf", "tf_static": "/tf_static",
             "events": "/trial/event", "action": "/hingelab/action", "object": "/object/pose", **spec.topics}
    plan, t = [], spec.gap_s
    for trial in spec.trials:
        plan.append((t, t + trial.duration_s, trial))
        t += trial.duration_s + spec.gap_s
    end_s = t
    storage = StoragePlugin.MCAP if spec.storage == "mcap" else StoragePlugin.SQLITE3
    messages = []  # (log ns, topic, msgtype, message)

    def add(log_s, topic, msg):
        messages.append((T0_NS + round(log_s * 1e9), topic, msg.__msgtype__, msg))

    def ns(t_s):
        return T0_NS + round(t_s * 1e9)

    static = [_tf(ts, ns(0), "world", "arm_base", np.eye(3), np.zeros(3)),
              _tf(ts, ns(0), "world", "camera_link", *CAMERA_IN_WORLD),
              _tf(ts, ns(0), "camera_link", CAMERA_OPTICAL, np.eye(3), np.zeros(3)),
              _tf(ts, ns(0), "flange", "hand_base", *HAND_IN_FLANGE)]
    add(0.0, names["tf_static"], T["tf2_msgs/msg/TFMessage"](transforms=static))
    n_joint = int(end_s * spec.joint_hz)
    joint_stamps = np.arange(n_joint) / spec.joint_hz
    if spec.non_monotonic_joints:
        for i in rng.choice(np.arange(10, n_joint - 2), spec.non_monotonic_joints, replace=False):
            joint_stamps[[i, i + 1]] = joint_stamps[[i + 1, i]]
    joint_names = list(ARM_JOINT_NAMES) + list(spec.hand_joint_names)
    for i, stamp_s in enumerate(joint_stamps):
        phase = 0.3 * np.arange(15)
        q, qdot = 0.2 * np.sin(0.8 * stamp_s + phase), 0.16 * np.cos(0.8 * stamp_s + phase)
        parts = [(joint_names, q, qdot, stamp_s)]
        if spec.split_joint_drivers:  # the hand's driver stamps 3 ms later than the arm's
            hand_s = stamp_s + 0.003
            qh = 0.2 * np.sin(0.8 * hand_s + phase)
            parts = [(joint_names[:6], q[:6], qdot[:6], stamp_s),
                     (joint_names[6:], qh[6:], 0.16 * np.cos(0.8 * hand_s + phase)[6:], hand_s)]
        for part_names, position, velocity, part_s in parts:
            add(i / spec.joint_hz + 0.005, names["joints"], T["sensor_msgs/msg/JointState"](
                header=_header(ts, ns(part_s)), name=part_names, position=position, velocity=velocity,
                effort=np.zeros(0)))
        add(i / spec.joint_hz + 0.001, names["tf"], T["tf2_msgs/msg/TFMessage"](
            transforms=[_tf(ts, ns(stamp_s), "arm_base", "flange", *flange_pose(stamp_s))]))
    cam_rot_w, cam_pos_w = CAMERA_IN_WORLD
    for i in range(int(end_s * spec.camera_hz)):
        stamp_s = i / spec.camera_hz
        hinge = 0.15 + 0.1 * np.sin(2.0 * stamp_s)
        tool = synth.from_tool_pose(tool_rot, tool_pos, hinge).astype(float)
        rh, ph = hand_in_world(stamp_s)
        world = tool @ rh.T + ph
        table = np.column_stack([rng.uniform(0.3, 0.7, spec.scene_points - len(tool)),
                                 rng.uniform(-0.3, 0.3, spec.scene_points - len(tool)),
                                 np.zeros(spec.scene_points - len(tool))])
        seen = table if i in spec.blind_frames else np.concatenate([world, table])
        cam = (seen - cam_pos_w) @ cam_rot_w  # world -> optical frame
        if spec.depth_images:
            info, image = _depth_messages(ts, ns(stamp_s), cam, spec.depth_size)
            add(stamp_s + 0.03, names["camera_info"], info)
            add(stamp_s + 0.03, names["depth"], image)
        else:
            add(stamp_s + 0.03, names["points"], point_cloud2(ts, ns(stamp_s), CAMERA_OPTICAL, cam))
        if spec.object_pose:
            obj = np.array([0.5, 0.02 * np.sin(stamp_s), 0.21])
            add(stamp_s + 0.03, names["object"], T["geometry_msgs/msg/PoseStamped"](
                header=_header(ts, ns(stamp_s), "world"),
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=obj[0], y=obj[1], z=obj[2]),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))))
    if spec.action:
        for i in range(int(end_s * 20)):
            add(i / 20 + 0.001, names["action"], T["std_msgs/msg/Float64MultiArray"](
                layout=T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
                data=np.array([np.sin(i / 7), np.cos(i / 9), 0.01, -0.02, 0.03 * np.sin(i / 5)])))
    trials = []
    for start_s, stop_s, trial in plan:
        events = [(start_s, "start")]
        for a in range(1, trial.attempts):
            at = start_s + trial.duration_s * a / (trial.attempts + 1)
            events += [(at - 0.01, "failure:missed_grasp"), (at, "attempt")]
        events.append((stop_s - 0.2,
                       {"success": "success", "failure": "failure:slip", "abort": "abort"}[trial.outcome]))
        if trial.end_event:
            events.append((stop_s, "end"))
        for at, text in events:
            add(at, names["events"], T["std_msgs/msg/String"](data=text))
        trials.append({"start_ns": ns(start_s), "end_ns": ns(stop_s), "trial": trial})
    messages.sort(key=lambda m: m[0])
    connections = {}
    with Writer(Path(path), version=9, storage_plugin=storage) as writer:
        for log_ns, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], log_ns, ts.serialize_cdr(msg, msgtype))
    return {"trials": trials, "messages": len(messages), "end_ns": messages[-1][0], "names": names}


def _depth_messages(ts, stamp_ns, points_optical, size):
    """A 32FC1 depth image (nearest return per pixel) of the points, and its camera_info."""
    width, height = size
    fx = fy = width / 2 / np.tan(np.radians(30))
    cx, cy = width / 2, height / 2
    z = points_optical[:, 2]
    front = z > 0.1
    u = np.round(points_optical[front, 0] / z[front] * fx + cx).astype(int)
    v = np.round(points_optical[front, 1] / z[front] * fy + cy).astype(int)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    depth = np.full((height, width), np.inf, np.float32)
    np.minimum.at(depth, (v[inside], u[inside]), z[front][inside].astype(np.float32))
    depth[~np.isfinite(depth)] = 0.0
    return (camera_info_message(ts, stamp_ns, CAMERA_OPTICAL, width, height, fx, fy, cx, cy),
            image_message(ts, stamp_ns, CAMERA_OPTICAL, depth))


def camera_info_message(ts, stamp_ns, frame_id, width, height, fx, fy, cx, cy):
    """A sensor_msgs/CameraInfo of a pinhole camera without distortion."""
    T = ts.types
    return T["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, stamp_ns, frame_id), height=height, width=width, distortion_model="plumb_bob",
        d=np.zeros(5), k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0]), r=np.eye(3).ravel(),
        p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1.0, 0]), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def image_message(ts, stamp_ns, frame_id, image: np.ndarray):
    """A sensor_msgs/Image of ``image`` (H, W): float32 as 32FC1 (a depth image in metres), uint8 as mono8."""
    image = np.ascontiguousarray(image)
    encoding = {np.dtype(np.float32): "32FC1", np.dtype(np.uint8): "mono8"}[image.dtype]
    height, width = image.shape
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, stamp_ns, frame_id), height=height, width=width, encoding=encoding, is_bigendian=0,
        step=width * image.itemsize, data=image.view(np.uint8).ravel())


__all__ = ["RigBagSpec", "RigTrial", "write_rig_bag", "point_cloud2", "camera_info_message", "image_message",
           "camera_in_hand", "CAMERA_OPTICAL", "T0_NS"]
