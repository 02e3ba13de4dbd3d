"""Per-step values <-> protobuf messages, one pair of functions per topic.

``encode_*`` functions take numpy values (units and frames as in ``schemas``) and
return the serialized message. ``decode_message`` turns any decoded message back
into ``{field: numpy array}``, the per-step view the reader stacks into columns.

Float fields travel as protobuf ``double`` (exact for float32 and float64);
``cast_fields`` restores the dtype the writer recorded in the channel metadata.
The cloud is the exception: it is raw float32 bytes in ``PointCloud.data``.
"""

from __future__ import annotations

import numpy as np
from google.protobuf.timestamp_pb2 import Timestamp
from scipy.spatial.transform import Rotation

from hingelab.episodes import schemas as S

_NS = 1_000_000_000
_FLOAT32 = S.PackedElementField.FLOAT32  # foxglove numeric type enum
_CLOUD_DATA_TAG = (6 << 3) | 2  # PointCloud.data: field 6, length-delimited


def timestamp(log_time_ns: int) -> Timestamp:
    return Timestamp(seconds=log_time_ns // _NS, nanos=log_time_ns % _NS)


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


# --- /tool/points -----------------------------------------------------------------
# The header of every cloud message (frame, stride, x/y/z fields) is the same: it is
# serialized once; a step adds its timestamp in front and its points behind. The
# result is byte-identical to PointCloud(...).SerializeToString() (tested), and
# keeps `data` last, which lets the reader slice the points out without a decode.
_CLOUD_HEADER = S.PointCloud(
    frame_id=S.FRAME_HAND,
    point_stride=12,
    fields=[S.PackedElementField(name=n, offset=4 * i, type=_FLOAT32) for i, n in enumerate("xyz")],
).SerializeToString()


def cloud_data_prefix(n_points: int) -> bytes:
    """Tag and length that precede the float32 points at the end of a cloud payload."""
    return bytes([_CLOUD_DATA_TAG]) + _varint(12 * n_points)


def encode_point_cloud(log_time_ns: int, points_hand: np.ndarray) -> bytes:
    """points_hand: (N, 3) float32, metres, hand_base frame -> foxglove.PointCloud bytes.

    The pose field is left unset: Foxglove reads that as the identity pose in
    ``frame_id``, so the points are drawn in hand_base.
    """
    stamp = timestamp(log_time_ns).SerializeToString()
    data = np.ascontiguousarray(points_hand, dtype="<f4").tobytes()
    # field 1 is always present (even empty at t=0), as protobuf writes a set message field
    return b"\x0a" + _varint(len(stamp)) + stamp + _CLOUD_HEADER + cloud_data_prefix(len(data) // 12) + data


def decode_point_cloud(message) -> np.ndarray:
    """foxglove.PointCloud with float32 x, y, z fields -> (N, 3) float32."""
    offsets = {f.name: (f.offset, f.type) for f in message.fields}
    if message.point_stride != 12 or offsets != {
        "x": (0, _FLOAT32), "y": (4, _FLOAT32), "z": (8, _FLOAT32)
    }:
        raise ValueError("point cloud is not packed float32 x, y, z with stride 12")
    return np.frombuffer(message.data, dtype="<f4").reshape(-1, 3)


# --- poses and positions ------------------------------------------------------------
def _pose(position, orientation_xyzw) -> dict:
    p = np.asarray(position, dtype=np.float64)
    q = np.asarray(orientation_xyzw, dtype=np.float64)
    return {
        "position": {"x": p[0], "y": p[1], "z": p[2]},
        "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


def encode_pose_in_frame(log_time_ns: int, position, orientation_xyzw) -> bytes:
    """Tool pose in hand_base: position (3,) metres, orientation (4,) quaternion x, y, z, w."""
    pose = _pose(position, orientation_xyzw)
    return S.PoseInFrame(
        timestamp=timestamp(log_time_ns), frame_id=S.FRAME_HAND, pose=pose
    ).SerializeToString()


def encode_frame_transform(log_time_ns: int, position, orientation_xyzw) -> bytes:
    pose = _pose(position, orientation_xyzw)
    return S.FrameTransform(
        timestamp=timestamp(log_time_ns), parent_frame_id=S.FRAME_HAND,
        child_frame_id=S.FRAME_TOOL, translation=pose["position"], rotation=pose["orientation"],
    ).SerializeToString()


def encode_camera_transform(log_time_ns: int, rotation, position) -> bytes:
    """The depth camera's optical frame in hand_base: R (3, 3) camera -> hand_base, position (3,) m."""
    quat = Rotation.from_matrix(np.asarray(rotation, float)).as_quat()  # x, y, z, w
    pose = _pose(position, quat)
    return S.FrameTransform(
        timestamp=timestamp(log_time_ns), parent_frame_id=S.FRAME_HAND,
        child_frame_id=S.FRAME_CAMERA, translation=pose["position"], rotation=pose["orientation"],
    ).SerializeToString()


def encode_depth_image(log_time_ns: int, depth_m: np.ndarray) -> bytes:
    """A depth image (H, W) metres (0: no return) as foxglove.RawImage 16UC1 millimetres (the camera's own format)."""
    depth = np.asarray(depth_m, dtype=np.float64)
    mm = np.clip(np.rint(depth * 1000.0), 0, 65535).astype("<u2")
    height, width = mm.shape
    return S.RawImage(timestamp=timestamp(log_time_ns), frame_id=S.FRAME_CAMERA, width=width, height=height,
                      encoding="16UC1", step=2 * width, data=mm.tobytes()).SerializeToString()


def decode_depth_image(message) -> np.ndarray:
    """foxglove.RawImage 16UC1 millimetres -> (H, W) float32 metres."""
    if message.encoding != "16UC1":
        raise ValueError(f"depth image encoding {message.encoding!r}, expected 16UC1")
    mm = np.frombuffer(message.data, dtype="<u2").reshape(message.height, message.width)
    return mm.astype(np.float32) / 1000.0


def encode_camera_calibration(log_time_ns: int, intrinsics) -> bytes:
    """``hingelab.camera.DepthIntrinsics`` as foxglove.CameraCalibration (no distortion: an undistorted image)."""
    k = intrinsics
    return S.CameraCalibration(
        timestamp=timestamp(log_time_ns), frame_id=S.FRAME_CAMERA, width=k.width, height=k.height,
        distortion_model="", D=[], K=[k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    ).SerializeToString()


def encode_point3(log_time_ns: int, position) -> bytes:
    """A point (3,) metres in hand_base as foxglove.Point3InFrame."""
    p = np.asarray(position, dtype=np.float64)
    return S.Point3InFrame(
        timestamp=timestamp(log_time_ns), frame_id=S.FRAME_HAND,
        point={"x": p[0], "y": p[1], "z": p[2]},
    ).SerializeToString()


def encode_joint_states(log_time_ns: int, names, position, velocity) -> bytes:
    """Hand joints: position (9,) rad, velocity (9,) rad/s, one JointState per name."""
    joints = [
        {"name": n, "position": float(p), "velocity": float(v)}
        for n, p, v in zip(names, position, velocity, strict=True)
    ]
    return S.JointStates(timestamp=timestamp(log_time_ns), joints=joints).SerializeToString()


def encode_fields(message_class, log_time_ns: int, **fields) -> bytes:
    """Any hingelab.* message from numpy fields (arrays become repeated doubles)."""
    values = {}
    for name, value in fields.items():
        if value is None:
            continue
        arr = np.asarray(value)
        values[name] = arr.ravel().tolist() if arr.ndim else arr.item()
    return message_class(timestamp=timestamp(log_time_ns), **values).SerializeToString()


# --- decoding into numpy ----------------------------------------------------------------
def _vec(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def _xyz(msg) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z], dtype=np.float64)


def _xyzw(msg) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z, msg.w], dtype=np.float64)


def decode_message(topic: str, message) -> dict[str, np.ndarray]:
    """A decoded per-step message -> {field: value} as the reader's columns name them.

    Fields the message does not carry (an empty repeated field) are left out.
    Returns {} for topics that have no array view (``/tf`` is a viewer copy).
    """
    if topic == S.TOPIC_POINTS:
        return {"points": decode_point_cloud(message)}
    if topic == S.TOPIC_TOOL_POSE:
        return {"position": _xyz(message.pose.position), "orientation": _xyzw(message.pose.orientation)}
    if topic == S.TOPIC_JOINTS:
        return {
            "position": _vec([j.position for j in message.joints]),
            "velocity": _vec([j.velocity for j in message.joints]),
        }
    if topic in (S.TOPIC_OBJECT, S.TOPIC_TARGET):
        return {"position": _xyz(message.point)}
    if topic == S.TOPIC_REWARD:
        out = {name: np.float64(v) for name, v in zip(message.names, message.values)}
        out["total"] = np.float64(message.total)
        return out
    if topic == S.TOPIC_STEP:
        out = {}
        for name in ("observation", "achieved_goal", "desired_goal", "action"):
            values = getattr(message, name)
            if len(values):
                out[name] = _vec(values)
        if not message.final:
            out["reward"] = np.float64(message.reward)
            out["terminated"] = np.bool_(message.terminated)
            out["truncated"] = np.bool_(message.truncated)
            for name, v in zip(message.info_names, message.info_values):
                out["info." + name] = np.float64(v)
        return out
    if topic in (S.TOPIC_LATENT, S.TOPIC_ACTION, S.TOPIC_GOAL, S.TOPIC_PRIVILEGED):
        out = {}
        for field in message.DESCRIPTOR.fields:
            if field.name in ("timestamp", "level"):
                continue
            value = getattr(message, field.name)
            if field.is_repeated:
                if len(value):
                    out[field.name] = _vec(value)
            elif field.type == field.TYPE_BOOL:
                out[field.name] = np.bool_(value)
            elif field.type == field.TYPE_UINT32:
                out[field.name] = np.int64(value)
            else:
                out[field.name] = np.float64(value)
        return out
    return {}


def cast_fields(fields: dict[str, np.ndarray], dtypes: dict[str, str] | None) -> dict[str, np.ndarray]:
    """Keep the fields the writer was given and restore their dtypes.

    ``dtypes`` is the channel's recorded {field: dtype}; proto3 cannot tell an unset
    scalar from a zero, so a field missing from it was never written. Without a
    record (a file from another writer) every decoded field is kept as decoded.
    """
    if dtypes is None:
        return fields
    return {k: np.asarray(v).astype(dtypes[k]) for k, v in fields.items() if k in dtypes}


def encode_columns(log_time_ns: int, length: int, columns: dict[str, np.ndarray]) -> bytes:
    """hingelab.EpisodeColumns: each array as (name, numpy dtype string, shape, raw little-endian bytes)."""
    packed = []
    for name, array in columns.items():
        array = np.ascontiguousarray(array)
        if array.dtype.byteorder == ">":
            array = array.astype(array.dtype.newbyteorder("<"))
        packed.append(S.Column(name=name, dtype=array.dtype.str, shape=list(array.shape), data=array.tobytes()))
    return S.EpisodeColumns(timestamp=timestamp(log_time_ns), length=length, columns=packed).SerializeToString()
