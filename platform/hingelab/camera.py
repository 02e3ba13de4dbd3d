"""Depth cameras as every part of the platform sees them: intrinsics and one frame.

A ``CameraFrame`` is what the cloud pipeline (``hingelab.perception.camera_cloud``) takes,
whether MuJoCo rendered it (``hingelab.sim.depth_render``) or a real driver or a ROS 2 bag
delivered it: a depth image in metres (0 where the camera returned nothing), the
intrinsics, the camera's pose in ``hand_base`` and, where known, a tool mask or a colour
image to make one from.

The Azure Kinect DK's depth modes (Microsoft's Azure Kinect DK hardware specification, its
depth camera table): NFOV unbinned 640 x 576 pixels, NFOV 2x2 binned 320 x 288, both with a
nominal field of view of 75 x 65 degrees and operating ranges of 0.5 to 3.86 m and 0.5 to
5.46 m. The intrinsics below are the undistorted pinhole image that the Sensor SDK's
``undistort`` example makes from the nominal field of view: for NFOV unbinned
fx = 320 / tan(37.5 deg) = 417.0 px, fy = 288 / tan(32.5 deg) = 452.1 px, principal point at
the image centre. A real rig replaces them with its own factory calibration (the ROS driver's
``camera_info``); nothing downstream assumes these numbers.

Frames: the camera's optical frame is OpenCV's and ROS's (x right, y down, z forward);
poses are (R (3, 3), t (3,)) with ``p_parent = R @ p_camera + t``; metres.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from hingelab.errors import ConfigError


@dataclass(frozen=True)
class DepthIntrinsics:
    """A pinhole depth camera: pixels, focal lengths and principal point in pixels, range in m."""

    mode: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    min_range_m: float
    max_range_m: float

    def __post_init__(self):
        if self.width < 1 or self.height < 1 or self.fx <= 0 or self.fy <= 0:
            raise ConfigError(f"depth intrinsics need positive size and focal lengths: {asdict(self)}")
        if not 0 <= self.min_range_m < self.max_range_m:
            raise ConfigError(f"depth range must satisfy 0 <= min < max: {self.min_range_m}, {self.max_range_m}")

    @property
    def matrix(self) -> np.ndarray:
        """K (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fovy_deg(self) -> float:
        return float(np.degrees(2 * np.arctan(self.height / 2 / self.fy)))

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, payload: dict) -> "DepthIntrinsics":
        return cls(**{k: payload[k] for k in cls.__dataclass_fields__})


def _pinhole_from_fov(mode: str, width: int, height: int, hfov_deg: float, vfov_deg: float,
                      min_range_m: float, max_range_m: float) -> DepthIntrinsics:
    fx = width / 2 / np.tan(np.radians(hfov_deg) / 2)
    fy = height / 2 / np.tan(np.radians(vfov_deg) / 2)
    return DepthIntrinsics(mode, width, height, float(fx), float(fy), width / 2, height / 2, min_range_m, max_range_m)


AZURE_KINECT_NFOV_UNBINNED = _pinhole_from_fov("azure_kinect_nfov_unbinned", 640, 576, 75.0, 65.0, 0.5, 3.86)
AZURE_KINECT_NFOV_BINNED = _pinhole_from_fov("azure_kinect_nfov_2x2binned", 320, 288, 75.0, 65.0, 0.5, 5.46)
DEPTH_MODES = {m.mode: m for m in (AZURE_KINECT_NFOV_UNBINNED, AZURE_KINECT_NFOV_BINNED)}


@dataclass
class CameraFrame:
    """One depth frame: the image, how to read it, where the camera was, and the tool's pixels if known."""

    depth: np.ndarray  # (H, W) float32, metres along the optical axis; 0: no return
    intrinsics: DepthIntrinsics
    camera_rotation: np.ndarray  # (3, 3) optical frame -> hand_base
    camera_position: np.ndarray  # (3,) the optical centre in hand_base
    tool_mask: np.ndarray | None = None  # (H, W) bool: the tool's pixels (segmentation, in simulation)
    rgb: np.ndarray | None = None  # (H, W, 3) uint8, registered to the depth image (real RGB-D frames)
    stamp_s: float = 0.0

    def __post_init__(self):
        shape = (self.intrinsics.height, self.intrinsics.width)
        if self.depth.shape != shape:
            raise ConfigError(f"depth image of shape {self.depth.shape} does not match the intrinsics' {shape} "
                              f"(mode {self.intrinsics.mode})")
        for name in ("tool_mask", "rgb"):
            image = getattr(self, name)
            if image is not None and image.shape[:2] != shape:
                raise ConfigError(f"{name} of shape {image.shape} does not match the depth image's {shape}")
