"""The camera cloud pipeline: a depth frame -> the tool's 256-point cloud in ``hand_base``.

The paper's chain on its Azure Kinect DK frames, one small function per step, so that each
runs alone on real frames, rendered ones or a ROS 2 bag's clouds:

1. ``depth_to_points``: depth image + intrinsics -> points in the camera's optical frame
   (only pixels with a return, only the tool's pixels when a mask is given);
2. ``transform``: into ``hand_base`` by the camera's pose there;
3. ``crop``: to the box around the tool in ``hand_base`` (``ToolCloudConfig.crop_low/high``);
4. the tool mask: from segmentation in simulation (``CameraFrame.tool_mask``), from the
   tweezer's colour and a depth window on real RGB-D frames (``colour_depth_mask``: it is
   printed in one colour), or none at all for a bare cloud (the crop alone);
5. ``remove_statistical_outliers``: points whose mean distance to their k nearest neighbours
   is more than ``std_ratio`` standard deviations above the cloud's mean (Open3D's rule);
6. ``voxel_downsample``: one point per occupied 2 mm voxel, the mean of its points (the
   grid starts at the cloud's minimum corner, as Open3D's does);
7. ``sample_exactly``: exactly 256 points, drawn without replacement, or every point plus
   random repeats when fewer remain (as the synthesized clouds refill their gaps).

``tool_cloud_from_frame`` runs them all; ``tool_cloud_from_points`` runs 3-7 on a cloud
already in ``hand_base``. A frame that leaves fewer than ``min_points`` voxels (an empty or
all-invalid depth image, the tool out of view) gives a ``ToolCloud`` whose ``points`` is None
and whose ``flag`` says why: the caller decides (the envs end the episode cleanly).
numpy and scipy only; Open3D is the benchmark's baseline (``hingelab bench perception``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from hingelab.camera import CameraFrame, DepthIntrinsics
from hingelab.errors import ConfigError

N_POINTS = 256


@dataclass(frozen=True)
class ToolCloudConfig:
    """The pipeline's settings; the crop box is in ``hand_base`` (m), around the tweezer held in its grasp."""

    crop_low: tuple[float, float, float] = (-0.14, -0.03, 0.05)
    crop_high: tuple[float, float, float] = (0.09, 0.11, 0.19)
    outlier_neighbours: int = 16
    outlier_std_ratio: float = 2.0
    voxel_m: float = 0.002
    n_points: int = N_POINTS
    min_points: int = 32  # voxels below which the frame is flagged instead of used

    def __post_init__(self):
        if not all(lo < hi for lo, hi in zip(self.crop_low, self.crop_high)):
            raise ConfigError(f"crop box needs low < high on every axis: {self.crop_low}, {self.crop_high}")
        if self.voxel_m <= 0 or self.n_points < 1 or self.outlier_neighbours < 1 or self.min_points < 1:
            raise ConfigError(f"voxel size, points, neighbours and min_points must be positive: {asdict(self)}")

    def to_json(self) -> dict:
        return asdict(self)


@dataclass
class ToolCloud:
    """The pipeline's result: ``points`` (n_points, 3) in hand_base, or None with ``flag`` saying why."""

    points: np.ndarray | None
    n_distinct: int  # distinct points among ``points`` (0 when flagged)
    flag: str | None = None  # "no_depth", "no_tool_pixels", "too_few_points"
    counts: dict = field(default_factory=dict)  # points left after each step


def depth_to_points(depth: np.ndarray, intrinsics: DepthIntrinsics, mask: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) float64 points in the optical frame from the pixels with a return (and in ``mask``)."""
    k = intrinsics
    keep = depth > 0
    if mask is not None:
        keep &= mask
    v, u = np.nonzero(keep)
    z = depth[v, u].astype(np.float64)
    return np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], axis=1)


def transform(points: np.ndarray, rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    return points @ np.asarray(rotation).T + np.asarray(position)


def crop(points: np.ndarray, low, high) -> np.ndarray:
    inside = np.all((points >= np.asarray(low)) & (points <= np.asarray(high)), axis=1)
    return points[inside]


def colour_depth_mask(rgb: np.ndarray, depth: np.ndarray, colour, tolerance: int = 40,
                      depth_range: tuple[float, float] = (0.3, 1.2)) -> np.ndarray:
    """(H, W) bool: pixels within ``tolerance`` of the tool's colour (per channel, 0-255) and within the depth
    window."""
    near = np.all(np.abs(rgb.astype(np.int16) - np.asarray(colour, np.int16)) <= tolerance, axis=-1)
    return near & (depth >= depth_range[0]) & (depth <= depth_range[1])


def remove_statistical_outliers(points: np.ndarray, neighbours: int = 16, std_ratio: float = 2.0) -> np.ndarray:
    """The points whose mean distance to their ``neighbours`` nearest others is at most mean + std_ratio * std."""
    if len(points) <= neighbours:
        return points
    distances, _ = cKDTree(points).query(points, k=neighbours + 1)
    mean = distances[:, 1:].mean(axis=1)  # column 0 is the point itself
    return points[mean <= mean.mean() + std_ratio * mean.std()]


def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point per occupied voxel: the mean of the points in it (grid from the cloud's minimum corner)."""
    if len(points) == 0:
        return points
    cells = np.floor((points - points.min(axis=0)) / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    sums = np.zeros((len(counts), 3))
    for axis in range(3):
        sums[:, axis] = np.bincount(inverse, weights=points[:, axis], minlength=len(counts))
    return sums / counts[:, None]


def sample_exactly(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly ``n`` points: a draw without replacement, or all of them plus random repeats."""
    if len(points) >= n:
        return points[rng.choice(len(points), n, replace=False)]
    extra = rng.choice(len(points), n - len(points), replace=True)
    return np.concatenate([points, points[extra]])[rng.permutation(n)]


def tool_cloud_from_points(points_hand: np.ndarray, config: ToolCloudConfig, rng: np.random.Generator,
                           counts: dict | None = None) -> ToolCloud:
    """Steps 3 and 5-7 on points already in ``hand_base`` (and masked, if a mask exists)."""
    counts = dict(counts or {})
    cropped = crop(points_hand, config.crop_low, config.crop_high)
    counts["cropped"] = len(cropped)
    kept = remove_statistical_outliers(cropped, config.outlier_neighbours, config.outlier_std_ratio)
    counts["inliers"] = len(kept)
    voxels = voxel_downsample(kept, config.voxel_m)
    counts["voxels"] = len(voxels)
    if len(voxels) < config.min_points:
        flag = "no_tool_pixels" if counts.get("tool_pixels", len(points_hand)) == 0 else "too_few_points"
        return ToolCloud(None, 0, flag, counts)
    return ToolCloud(sample_exactly(voxels, config.n_points, rng).astype(np.float32),
                     min(len(voxels), config.n_points), None, counts)


def tool_cloud_from_frame(frame: CameraFrame, config: ToolCloudConfig, rng: np.random.Generator,
                          mask: np.ndarray | None = None) -> ToolCloud:
    """The whole chain on one frame. ``mask`` overrides the frame's own tool mask."""
    mask = frame.tool_mask if mask is None else mask
    valid = int(np.count_nonzero(frame.depth > 0))
    counts = {"valid_pixels": valid}
    if valid == 0:
        return ToolCloud(None, 0, "no_depth", counts)
    points = depth_to_points(frame.depth, frame.intrinsics, mask)
    counts["tool_pixels"] = len(points)
    if len(points) == 0:
        return ToolCloud(None, 0, "no_tool_pixels", counts)
    return tool_cloud_from_points(transform(points, frame.camera_rotation, frame.camera_position), config, rng, counts)
