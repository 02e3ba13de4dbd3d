"""ROS messages <-> numpy: PointCloud2, depth images, camera info, transforms, joint states.

Frames: a pose is (R (3, 3), t (3,)) with ``p_parent = R @ p_child + t``; quaternions are
ROS's (x, y, z, w). Clouds are float32 metres.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.camera import DepthIntrinsics
from hingelab.episodes.errors import DatasetError

POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
FLOAT32 = 7


def stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def frame_name(frame_id: str) -> str:
    """tf2 frame ids carry no leading slash (ROS 1 habits do)."""
    return frame_id.lstrip("/")


def check_point_cloud2(msg, where: str) -> None:
    """A one-line ``DatasetError`` naming ``where`` (the bag, topic and stamp) unless the PointCloud2's header
    describes its data: point_step > 0, every field of a known datatype and within point_step, rows of at
    least width * point_step bytes (row_step), data of exactly height * row_step bytes."""
    step, width, height, row_step = int(msg.point_step), int(msg.width), int(msg.height), int(msg.row_step)
    if step <= 0:
        raise DatasetError(f"{where}: PointCloud2 with point_step {step}; a point takes at least one byte")
    for f in msg.fields:
        if f.datatype not in POINTFIELD_DTYPES:
            raise DatasetError(f"{where}: PointCloud2 field {f.name!r} has the unknown datatype {f.datatype} "
                               f"(sensor_msgs/PointField knows {min(POINTFIELD_DTYPES)} to {max(POINTFIELD_DTYPES)})")
        end = int(f.offset) + np.dtype(POINTFIELD_DTYPES[f.datatype]).itemsize * max(int(f.count), 1)
        if end > step:
            raise DatasetError(f"{where}: PointCloud2 field {f.name!r} ends at byte {end} (offset {f.offset}), "
                               f"beyond its point_step {step}")
    if row_step < width * step:
        raise DatasetError(f"{where}: PointCloud2 with row_step {row_step}, less than width {width} x point_step "
                           f"{step} = {width * step}")
    if len(msg.data) != height * row_step:
        raise DatasetError(f"{where}: PointCloud2 holds {len(msg.data)} bytes of data, not height {height} x "
                           f"row_step {row_step} = {height * row_step}")


def cloud_xyz(msg, where: str) -> np.ndarray:
    """(N, 3) float64 points of a PointCloud2 (x, y, z fields); points with a NaN or inf coordinate dropped.
    A header that does not describe the data is a one-line ``DatasetError`` (``check_point_cloud2``)."""
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in "xyz" if n not in fields]
    if missing:
        raise DatasetError(f"{where}: PointCloud2 without the field(s) {', '.join(missing)}; the import needs x, y, z")
    check_point_cloud2(msg, where)
    endian = ">" if msg.is_bigendian else "<"
    dtype = np.dtype({"names": list("xyz"),
                      "formats": [endian + POINTFIELD_DTYPES[fields[n].datatype] for n in "xyz"],
                      "offsets": [fields[n].offset for n in "xyz"], "itemsize": msg.point_step})
    n = int(msg.width) * int(msg.height)
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.row_step != msg.width * msg.point_step:  # padded rows
        data = data.reshape(msg.height, msg.row_step)[:, :msg.width * msg.point_step].reshape(-1)
    data = np.ascontiguousarray(data[:n * msg.point_step])
    packed = all(fields[n_].datatype == FLOAT32 and fields[n_].offset == 4 * i for i, n_ in enumerate("xyz"))
    if packed and not msg.is_bigendian and msg.point_step % 4 == 0:
        # the usual layout (x y z float32 first, e.g. the Azure Kinect driver's, padded or with rgb after):
        # a view of the bytes, filtered before the float64 copy (a real-size cloud is ~200k points)
        xyz = data.view("<f4").reshape(n, msg.point_step // 4)[:, :3]
        return xyz[np.isfinite(xyz).all(axis=1)].astype(np.float64)
    rec = np.frombuffer(data, dtype=dtype, count=n)
    points = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    return points[np.isfinite(points).all(axis=1)]


def depth_image_m(msg, where: str) -> np.ndarray:
    """(H, W) float32 metres from a 32FC1 (metres) or 16UC1 (millimetres) image; no return = 0."""
    encoding = msg.encoding.upper()
    if encoding not in ("32FC1", "16UC1", "MONO16"):
        raise DatasetError(f"{where}: depth image encoding {msg.encoding!r}; the import reads 32FC1 metres "
                           "(or 16UC1 millimetres)")
    itemsize = 4 if encoding == "32FC1" else 2
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if step < width * itemsize or len(msg.data) != height * step:
        raise DatasetError(f"{where}: depth image of {width} x {height} {msg.encoding} with step {step} holds "
                           f"{len(msg.data)} bytes of data, not height x step = {height * step} (with step at least "
                           f"{width * itemsize})")
    dtype = np.dtype((">" if msg.is_bigendian else "<") + ("f4" if itemsize == 4 else "u2"))
    data = np.asarray(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)[:, :msg.width * itemsize]
    image = np.frombuffer(data.tobytes(), dtype=dtype).reshape(msg.height, msg.width).astype(np.float32)
    if itemsize == 2:
        image = image / 1000.0
    image[~np.isfinite(image)] = 0.0
    return image


def mask_image(msg, where: str) -> np.ndarray:
    """(H, W) bool from a mono8 or 8UC1 image: nonzero pixels are in the mask."""
    if msg.encoding.upper() not in ("MONO8", "8UC1"):
        raise DatasetError(f"{where}: mask image encoding {msg.encoding!r}; the import reads mono8 or 8UC1 "
                           "(nonzero: the object)")
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if step < width or len(msg.data) != height * step:
        raise DatasetError(f"{where}: mask image of {width} x {height} with step {step} holds {len(msg.data)} bytes "
                           f"of data, not height x step = {height * step} (with step at least {width})")
    return np.asarray(msg.data, dtype=np.uint8).reshape(height, step)[:, :width] != 0


def intrinsics_from_camera_info(msg) -> DepthIntrinsics:
    k = np.asarray(msg.k, float)
    return DepthIntrinsics("ros2_camera_info", int(msg.width), int(msg.height), float(k[0]), float(k[4]),
                           float(k[2]), float(k[5]), 0.0, 100.0)


def transform_pose(transform) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a geometry_msgs/Transform."""
    q, p = transform.rotation, transform.translation
    return Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), np.array([p.x, p.y, p.z], float)


def pose_pose(pose) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a geometry_msgs/Pose."""
    q, p = pose.orientation, pose.position
    return Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), np.array([p.x, p.y, p.z], float)


def quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(np.asarray(rotation, float)).as_quat()


__all__ = ["check_point_cloud2", "cloud_xyz", "depth_image_m", "mask_image", "intrinsics_from_camera_info",
           "transform_pose", "pose_pose", "quaternion_xyzw", "stamp_ns", "frame_name"]
