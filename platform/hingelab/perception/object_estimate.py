"""The object as the depth camera sees it: its points through a segmentation mask, and its position from them.

The paper's rig segments the object in the RGB image, takes the masked depth pixels' points and
"calculated its centroid to determine the target object's position". A single view sees only the
object's near side, so that centroid lies toward the camera (up to half the object's depth along the
viewing ray). This module gives the chain and the estimators, one function each, named so an episode
can say which one it used:

1. the mask: the rig's segmentation, or the simulator's (``hingelab.sim.object_render``) made as
   imperfect as a real segmenter by ``MaskErrors`` (boundary eroded or dilated by a pixel or two,
   missed pixels, now and then a wrong blob near the object; seeded);
2. ``object_cloud``: the masked pixels -> points (``camera_cloud.depth_to_points``), into the frame's
   parent frame (``camera_cloud.transform``), cropped to the platform's box (``camera_cloud.crop``),
   statistical outliers removed (``camera_cloud.remove_statistical_outliers``); or, with no mask at all
   (a rig that logged no segmentation), ``object_cloud_from_scene``: the scene's points in the box over
   the platform (its footprint, from just above its top), minus those near the tool's points;
3. the estimators on the visible points (``points``: (N, 3), m, in the frame's parent frame, e.g. the
   world; ``camera_position``: (3,), the optical centre in the same frame):

   * ``centroid``: the mean of the visible points (the paper's);
   * ``ray_corrected``: the centroid moved away from the camera along the viewing ray by half the
     visible points' depth extent along that ray;
   * ``primitive_fit``: the centre of a sphere fitted to the visible points (geometric least squares,
     its radius bounded by the visible width across the ray): exact for a sphere, an approximation for
     the other shapes;
   * ``mesh_fit``: the object's known model (``hingelab.perception.object_model_fit``) fitted to the
     visible points by a trimmed ICP over its position and yaw, from the ray_corrected estimate: needs
     ``object_model`` (the others take it and ignore it);
   * ``TemporalFilter``: the per-axis median of the last few frames' estimates of any of them;

   and ``visible_extent``, the visible points' axis-aligned bounding box (what a detection's box gives).

A frame that gives no estimate (no depth, no object pixels, the object hidden by the tool, off the
platform, too few points) gives an ``ObjectEstimate`` whose ``estimate`` is None and whose ``flag``
says why, never an exception: the caller decides (as with ``camera_cloud.ToolCloud``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from hingelab.camera import CameraFrame
from hingelab.errors import ConfigError
from hingelab.perception.camera_cloud import crop, depth_to_points, remove_statistical_outliers, transform
from hingelab.perception.object_model_fit import ObjectModel, fit_model

EXTENT_PERCENTILES = (2.0, 98.0)  # the depth extent along the ray, robust to a stray noisy point
TOOL_CLEARANCE_M = 0.005  # object_cloud_from_scene: scene points this near a tool point are the tool's
SURFACE_SIGMAS = 4.0  # object_cloud_from_scene: the object's points are this many noise sigmas over the surface
CLUSTER_LINK_M = 0.005  # object_cloud_from_scene: points this near are one object (pixels are ~1.6 mm apart at 0.65 m)
RESTING_M = 0.01  # object_cloud_from_scene: a cluster whose lowest point is this near the surface rests on it


@dataclass(frozen=True)
class MaskErrors:
    """How a real segmentation mask departs from the true one, drawn anew per frame.

    The boundary moves by k pixels, k uniform in [-boundary_px, boundary_px] (negative: eroded,
    positive: dilated); ``missed`` of the object's pixels are dropped at random; with probability
    ``wrong_blob`` a disc of ``blob_radius_px`` pixels, ``blob_offset_px`` from the mask's centre,
    is added (a wrongly segmented patch nearby). The values are chosen, not fitted to a segmenter."""

    boundary_px: int = 2
    missed: float = 0.05
    wrong_blob: float = 0.1
    blob_radius_px: tuple[int, int] = (2, 5)
    blob_offset_px: tuple[int, int] = (10, 40)

    def __post_init__(self):
        if self.boundary_px < 0 or not 0 <= self.missed < 1 or not 0 <= self.wrong_blob <= 1:
            raise ConfigError(f"mask errors need boundary_px >= 0, missed in [0, 1), wrong_blob in [0, 1]: "
                              f"{asdict(self)}")
        if not (1 <= self.blob_radius_px[0] <= self.blob_radius_px[1]
                and 0 <= self.blob_offset_px[0] <= self.blob_offset_px[1]):
            raise ConfigError(f"blob radius and offset ranges need 1 <= low <= high: {asdict(self)}")

    def to_json(self) -> dict:
        return asdict(self)

    def apply(self, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A corrupted copy of ``mask`` (H, W) bool. The same draws whatever the mask holds, so a seed gives
        the same errors on every frame of the same size."""
        mask = np.asarray(mask, bool)
        k = int(rng.integers(-self.boundary_px, self.boundary_px + 1))
        missed = rng.random(mask.shape) < self.missed
        blob = rng.random() < self.wrong_blob
        angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(*self.blob_offset_px)
        radius = rng.uniform(self.blob_radius_px[0], self.blob_radius_px[1])
        out = mask.copy()
        if k > 0:
            out = ndimage.binary_dilation(out, iterations=k)
        elif k < 0:
            out = ndimage.binary_erosion(out, iterations=-k)
        out &= ~missed
        if blob and mask.any():
            v, u = np.nonzero(mask)
            cv, cu = v.mean() + distance * np.sin(angle), u.mean() + distance * np.cos(angle)
            rows, cols = np.ogrid[:mask.shape[0], :mask.shape[1]]
            out |= (rows - cv) ** 2 + (cols - cu) ** 2 <= radius ** 2
        return out


NO_MASK_ERRORS = MaskErrors(0, 0.0, 0.0)


@dataclass(frozen=True)
class ObjectCloudConfig:
    """The chain's settings. The crop box is in the frame's parent frame (m); None: no crop."""

    crop_low: tuple[float, float, float] | None = None
    crop_high: tuple[float, float, float] | None = None
    outlier_neighbours: int = 8
    outlier_std_ratio: float = 2.0
    min_pixels: int = 8  # object pixels with a return below which the frame is flagged
    min_points: int = 8  # points after the crop and the outlier removal below which it is flagged

    def __post_init__(self):
        if (self.crop_low is None) != (self.crop_high is None):
            raise ConfigError("give both crop_low and crop_high, or neither")
        if self.crop_low is not None and not all(lo < hi for lo, hi in zip(self.crop_low, self.crop_high)):
            raise ConfigError(f"crop box needs low < high on every axis: {self.crop_low}, {self.crop_high}")
        if self.outlier_neighbours < 1 or self.min_pixels < 1 or self.min_points < 1:
            raise ConfigError(f"neighbours, min_pixels and min_points must be positive: {asdict(self)}")

    def to_json(self) -> dict:
        return asdict(self)


@dataclass
class ObjectCloud:
    """The visible points (N, 3) in the frame's parent frame, or None with ``flag`` saying why."""

    points: np.ndarray | None
    flag: str | None = None  # "no_depth", "no_object_pixels", "hidden_by_tool", "too_few_pixels",
    #                          "off_platform", "too_few_points"; from_scene: "no_object_points"
    counts: dict = field(default_factory=dict)  # pixels or points left after each step


@dataclass
class ObjectEstimate:
    """One frame's (or the filter's) estimate: centre (3,) and visible extent (3,), m, or None and a flag."""

    estimate: np.ndarray | None
    extent: np.ndarray | None
    estimator: str
    flag: str | None = None
    n_points: int = 0
    counts: dict = field(default_factory=dict)


def object_cloud(frame: CameraFrame, mask: np.ndarray, config: ObjectCloudConfig = ObjectCloudConfig(),
                 prior: np.ndarray | None = None) -> ObjectCloud:
    """Steps 2 of the module doc on one frame. ``mask`` (H, W) bool: the object's pixels. ``prior`` (3,): where
    the object was last seen (parent frame), to tell an object the tool hides from one that is not there."""
    counts = {"valid_pixels": int(np.count_nonzero(frame.depth > 0))}
    if counts["valid_pixels"] == 0:
        return ObjectCloud(None, "no_depth", counts)
    mask = np.asarray(mask, bool)
    counts["object_pixels"] = int(np.count_nonzero(mask & (frame.depth > 0)))
    if counts["object_pixels"] < config.min_pixels:
        if _tool_hides(frame, mask, prior):
            flag = "hidden_by_tool"
        else:
            flag = "no_object_pixels" if counts["object_pixels"] == 0 else "too_few_pixels"
        return ObjectCloud(None, flag, counts)
    points = transform(depth_to_points(frame.depth, frame.intrinsics, mask), frame.camera_rotation,
                       frame.camera_position)
    if config.crop_low is not None:
        points = crop(points, config.crop_low, config.crop_high)
    counts["cropped"] = len(points)
    if len(points) < config.min_points:
        return ObjectCloud(None, "off_platform", counts)
    points = remove_statistical_outliers(points, config.outlier_neighbours, config.outlier_std_ratio)
    counts["inliers"] = len(points)
    if len(points) < config.min_points:
        return ObjectCloud(None, "too_few_points", counts)
    return ObjectCloud(points, None, counts)


def object_cloud_from_scene(points: np.ndarray, config: ObjectCloudConfig, tool_points: np.ndarray | None = None,
                            tool_clearance_m: float = TOOL_CLEARANCE_M) -> ObjectCloud:
    """Step 2 without a mask: the object's points segmented by geometry alone. ``points`` (N, 3): the scene's
    points in the parent frame (z up; a whole depth image's, or a scene cloud's); ``config``'s crop box: the box
    over the platform (its footprint, from just above its top). Kept:

    1. the points inside the footprint, above the platform's surface as this frame sees it by more than its
       noise (``platform_surface``: the floor is the higher of the box's and the surface + 4 noise sigmas; a
       camera's noise and its calibration put the surface's own points a mm or two off the model's top) and
       below the box's top: the platform, the table and the arm drop out;
    2. minus those within ``tool_clearance_m`` of ``tool_points`` (M, 3), the frame's tool cloud in the same
       frame where it is known (the tweezer's tips reach into the box when they grasp);
    3. of what is left, grouped into clusters (points chained by steps of at most ``CLUSTER_LINK_M``), the
       largest that rests on the platform (its lowest point within ``RESTING_M`` of the surface): one object on
       the platform, as on the rig; the surface noise's stray points and parts of the hand or tool over the
       object float;
    4. the statistical outliers removed.

    Flags: ``hidden_by_tool`` (the tool's points took at least ``min_points`` of the box's and left no resting
    cluster of ``min_points``), else ``no_object_points`` (nothing rests on the platform: the object out of
    view, lifted, or not there) or ``too_few_points`` (a resting cluster, of fewer than ``min_points``)."""
    if config.crop_low is None:
        raise ConfigError("object_cloud_from_scene needs the crop box over the platform (crop_low, crop_high)")
    points = np.asarray(points, float)
    counts = {"scene_points": len(points)}
    low, high = np.array(config.crop_low, float), np.array(config.crop_high, float)
    inside = (points[:, :2] >= low[:2]).all(axis=1) & (points[:, :2] <= high[:2]).all(axis=1)
    surface, noise = platform_surface(points[inside, 2], low[2])
    floor = low[2] if surface is None else max(low[2], surface + SURFACE_SIGMAS * noise)
    points = points[inside & (points[:, 2] > floor) & (points[:, 2] <= high[2])]
    counts["cropped"] = len(points)
    if len(points) < config.min_points:
        return ObjectCloud(None, "no_object_points", counts)
    if tool_points is not None and len(tool_points):
        distance, _ = cKDTree(np.asarray(tool_points, float)).query(points, distance_upper_bound=tool_clearance_m)
        points = points[~np.isfinite(distance)]  # inf: no tool point within the clearance
        counts["off_tool"] = len(points)
    labels = cluster_labels(points, CLUSTER_LINK_M)
    resting = [c for c in np.unique(labels) if points[labels == c, 2].min() <= floor + RESTING_M]
    sizes = [int(np.count_nonzero(labels == c)) for c in resting]
    points = points[labels == resting[int(np.argmax(sizes))]] if resting else points[:0]
    counts["cluster"] = len(points)
    if len(points) >= config.min_points:
        points = remove_statistical_outliers(points, config.outlier_neighbours, config.outlier_std_ratio)
        counts["inliers"] = len(points)
    if len(points) < config.min_points:
        hidden = counts["cropped"] - counts.get("off_tool", counts["cropped"]) >= config.min_points
        flag = "hidden_by_tool" if hidden else ("too_few_points" if resting else "no_object_points")
        return ObjectCloud(None, flag, counts)
    return ObjectCloud(points, None, counts)


def platform_surface(heights: np.ndarray, floor: float, band_m: float = 0.01,
                     min_points: int = 50) -> tuple[float | None, float]:
    """(height, noise sigma) m of the platform's surface from the heights (N,) of the points over its footprint:
    the median and 1.4826 x the median absolute deviation of those within ``band_m`` of the crop's ``floor`` (most
    are the surface's own; the object's few do not move a median); (None, 0) with fewer than ``min_points``
    (the camera does not see the platform)."""
    band = heights[np.abs(heights - floor) <= band_m]
    if len(band) < min_points:
        return None, 0.0
    middle = float(np.median(band))
    return middle, 1.4826 * float(np.median(np.abs(band - middle)))


def cluster_labels(points: np.ndarray, link_m: float) -> np.ndarray:
    """(N,) int: the points' (N, 3) groups, members chained by steps of at most ``link_m``."""
    if len(points) < 2:
        return np.zeros(len(points), int)
    pairs = cKDTree(points).query_pairs(link_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    return connected_components(graph, directed=False)[1]


def _tool_hides(frame: CameraFrame, mask: np.ndarray, prior: np.ndarray | None, window_px: int = 3) -> bool:
    """The tool's pixels cover the prior's projection (within ``window_px``), or, without a prior, border the
    few object pixels there are."""
    if frame.tool_mask is None:
        return False
    tool = np.asarray(frame.tool_mask, bool)
    if prior is not None:
        p = np.asarray(frame.camera_rotation).T @ (np.asarray(prior, float) - np.asarray(frame.camera_position))
        if p[2] <= 0:
            return False
        k = frame.intrinsics
        u, v = int(round(k.fx * p[0] / p[2] + k.cx)), int(round(k.fy * p[1] / p[2] + k.cy))
        window = tool[max(v - window_px, 0):v + window_px + 1, max(u - window_px, 0):u + window_px + 1]
        return bool(window.any())
    return bool(mask.any() and (ndimage.binary_dilation(mask, iterations=2) & tool).any())


# ---------------------------------------------------------------------- estimators
def centroid(points: np.ndarray, camera_position: np.ndarray | None = None,
             object_model: ObjectModel | None = None) -> np.ndarray:
    """The mean of the visible points (the paper's estimate); ``camera_position`` and ``object_model`` are unused."""
    return np.asarray(points, float).mean(axis=0)


def viewing_ray(points: np.ndarray, camera_position: np.ndarray) -> np.ndarray:
    """(3,) unit vector from the camera through the points' centroid."""
    ray = centroid(points) - np.asarray(camera_position, float)
    return ray / np.linalg.norm(ray)


def depth_extent(points: np.ndarray, camera_position: np.ndarray) -> float:
    """The visible points' extent along the viewing ray, m (between the ``EXTENT_PERCENTILES``)."""
    depths = (np.asarray(points, float) - np.asarray(camera_position, float)) @ viewing_ray(points, camera_position)
    low, high = np.percentile(depths, EXTENT_PERCENTILES)
    return float(high - low)


def ray_corrected(points: np.ndarray, camera_position: np.ndarray,
                  object_model: ObjectModel | None = None) -> np.ndarray:
    """The centroid moved away from the camera along the viewing ray by half the visible depth extent
    (``object_model`` is unused)."""
    return centroid(points) + viewing_ray(points, camera_position) * depth_extent(points, camera_position) / 2


def visible_width(points: np.ndarray, camera_position: np.ndarray) -> float:
    """The visible points' largest extent across the viewing ray, m (the silhouette's width)."""
    ray = viewing_ray(points, camera_position)
    rel = np.asarray(points, float) - centroid(points)
    across = rel - np.outer(rel @ ray, ray)
    return float(np.max(np.linalg.norm(across[:, None] - across[None], axis=-1))) if len(rel) < 2000 else \
        float(2 * np.max(np.linalg.norm(across, axis=1)))


def fit_sphere(points: np.ndarray, camera_position: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of the sphere nearest the visible points (geometric least squares, soft-L1 loss),
    its radius bounded to 0.4-0.6 of the visible width (a sphere's silhouette is its diameter)."""
    points = np.asarray(points, float)
    width = max(visible_width(points, camera_position), 1e-4)
    low, high = 0.4 * width, 0.6 * width
    start = np.concatenate([ray_corrected(points, camera_position), [width / 2]])

    def residuals(x):
        return np.linalg.norm(points - x[:3], axis=1) - x[3]

    result = least_squares(residuals, start, bounds=([-np.inf] * 3 + [low], [np.inf] * 3 + [high]),
                           loss="soft_l1", f_scale=0.002)
    return result.x[:3], float(result.x[3])


def primitive_fit(points: np.ndarray, camera_position: np.ndarray,
                  object_model: ObjectModel | None = None) -> np.ndarray:
    """The centre of ``fit_sphere``; ``object_model`` is unused."""
    return fit_sphere(points, camera_position)[0]


def mesh_fit(points: np.ndarray, camera_position: np.ndarray, object_model: ObjectModel | None = None) -> np.ndarray:
    """The centre of the object's model fitted to the visible points (``object_model_fit.fit_model``)."""
    if object_model is None:
        raise ConfigError("the mesh_fit estimator needs the object's model (ObjectModel.from_mujoco); "
                          "without one, use ray_corrected")
    return fit_model(points, camera_position, object_model, ray_corrected(points, camera_position)).centre


def visible_extent(points: np.ndarray) -> np.ndarray:
    """(3,) the visible points' bounding box along the parent frame's axes, m."""
    points = np.asarray(points, float)
    return points.max(axis=0) - points.min(axis=0)


ESTIMATORS = {"centroid": centroid, "ray_corrected": ray_corrected, "primitive_fit": primitive_fit,
              "mesh_fit": mesh_fit}
MODEL_ESTIMATORS = ("mesh_fit",)  # the estimators that need the object's model


def estimate_object(frame: CameraFrame, mask: np.ndarray, estimator: str = "centroid",
                    config: ObjectCloudConfig = ObjectCloudConfig(), prior: np.ndarray | None = None,
                    cloud: ObjectCloud | None = None, object_model: ObjectModel | None = None) -> ObjectEstimate:
    """The chain and one named estimator on one frame (``cloud``: reuse one ``object_cloud`` made already;
    ``object_model``: the object's, for ``mesh_fit``)."""
    if estimator not in ESTIMATORS:
        raise ConfigError(f"unknown object estimator {estimator!r}; choose one of {', '.join(ESTIMATORS)}")
    cloud = cloud if cloud is not None else object_cloud(frame, mask, config, prior)
    return estimate_from_cloud(cloud, estimator, frame.camera_position, object_model)


def estimate_from_cloud(cloud: ObjectCloud, estimator: str, camera_position: np.ndarray,
                        object_model: ObjectModel | None = None) -> ObjectEstimate:
    """One named estimator on an ``ObjectCloud`` (either way of step 2); ``camera_position`` (3,): the optical
    centre in the cloud's frame; ``object_model``: the object's, for ``mesh_fit``."""
    if estimator not in ESTIMATORS:
        raise ConfigError(f"unknown object estimator {estimator!r}; choose one of {', '.join(ESTIMATORS)}")
    if cloud.points is None:
        return ObjectEstimate(None, None, estimator, cloud.flag, 0, cloud.counts)
    estimate = ESTIMATORS[estimator](cloud.points, np.asarray(camera_position, float), object_model)
    return ObjectEstimate(np.asarray(estimate, float), visible_extent(cloud.points), estimator, None,
                          len(cloud.points), cloud.counts)


class TemporalFilter:
    """The per-axis median of the last ``window`` good estimates (a flagged frame adds none): for an object at
    rest, it averages out frame-to-frame noise and outvotes an occasional wrong blob; it cannot remove a bias
    that every frame shares, and it lags an object that moves."""

    def __init__(self, window: int = 5):
        if window < 1:
            raise ConfigError(f"the temporal filter's window must be positive, not {window}")
        self.window = window
        self._estimates: list[np.ndarray] = []

    def reset(self) -> None:
        self._estimates.clear()

    def update(self, estimate: np.ndarray | None) -> np.ndarray | None:
        """Add this frame's estimate (None: a flagged frame) and return the filtered one (None before any)."""
        if estimate is not None:
            self._estimates = (self._estimates + [np.asarray(estimate, float)])[-self.window:]
        return np.median(self._estimates, axis=0) if self._estimates else None
