"""SVD registration of tool clouds to the canonical cloud: the tool pose in ``hand_base``.

No correspondences are given, so registration alternates nearest neighbours and the
SVD (Kabsch) solution for the best rigid motion (ICP, point to point), batched over
many clouds at once. What makes it reliable and fast on the tweezer:

* **Initialization** (no prior pose): the tweezer is long and thin, so the cloud's
  principal axis is the leg direction; the remaining freedom is the sign of that axis
  and the roll about it. ``2 * n_roll`` hypotheses (both signs, rolls every 360/n_roll
  degrees) each get a few coarse iterations on a subsample; the ``keep_hypotheses`` with
  the smallest trimmed residual go on, and the best after the fine iterations wins.
  With a prior (the previous frame's pose, or the nominal in-hand pose) the hypotheses
  are the prior turned about the tool's long axis by up to ``prior_roll_rad`` either way:
  the roll about the long axis of this flat tool is where point-to-point ICP is weakest
  (a wrong roll is a deep local minimum; a flip of the nearly mirror-symmetric tweezer
  fits almost as well as the truth under 3-5 mm noise, so no global search can tell
  them apart reliably: a prior within ~60 degrees is what makes registration robust).
* **Articulation**: the canonical cloud is the tool at a reference opening, but the
  opening varies and leg b's points would pull a rigid fit half-way towards leg b.
  After the coarse stage each point is matched to the nearer of leg a (tool frame)
  and leg b (leg b's frame at the current hinge estimate); the hinge angle gets its
  own closed-form update (2-D Procrustes about the hinge axis). The pose returned is
  leg a's frame, the tool frame, whatever the opening. ``articulated=False`` gives
  the plain rigid registration against the reference-opening cloud.
* **Nearest neighbours**: the canonical parts are fixed, so their nearest-point maps
  are precomputed once on a voxel grid (an O(1) lookup per point); the last
  iterations use exact queries (the numpy path: scipy ``cKDTree``; compiled: below).
* Trimmed: the worst ``trim_fraction`` of pairs are left out of each SVD.
* **Compiled**: the iterations of ``register`` (without reverse pairs) and of ``track`` run in
  numba kernels (``hingelab.perception.registration_kernels``; exact neighbours there come from
  cell lists seeded by the voxel map); ``numpy_reference()`` gives the same results in numpy.
* **Tracking** (``track``, used by ``ToolState`` between resets): one hypothesis, started at
  the pose predicted from the previous frame, with a motion prior. A single frame pins the
  roll about the long axis down only to a few degrees (the legs are 16 mm tall, the noise 3 mm),
  so independent registrations of a resting tool differ by that much from frame to frame;
  with the prior each update is a MAP estimate, which holds the poorly observed directions
  (the roll, the slide along the legs) near the prediction and leaves the well observed ones
  to the data. Its iterations are point-to-plane Gauss-Newton steps (model normals by PCA
  over the surface bank): point-to-point ICP slides along the legs only a fraction of the
  way per iteration. ``TrackingConfig`` holds its settings, apart from ``RegistrationConfig``
  (which the encoder checkpoint records for the fresh registration; tracking leaves it alone).

Frames and units: clouds (N, 3) or (B, N, 3) metres in ``hand_base``; the result's
``rotation`` R and ``translation`` t map tool-frame points into hand_base
(``p_hand = R @ p_tool + t``); Euler angles are extrinsic x-y-z (roll, pitch, yaw), rad.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from hingelab.errors import ConfigError
from hingelab.perception import pose_kernels, registration_kernels
from hingelab.perception.clouds import ToolGeometry, _even_subset

EXACT_CELL_M = 0.005  # cells of the compiled loops' exact nearest-neighbour search (smaller ones are slower)
CORE_MARGIN_M = 0.01  # the voxel map's block that tracking looks in first (_GridNearest.core): 3 sigma of noise
MIN_POINTS = 32  # fewer points than this cannot pin down a 6-DoF pose of a long thin tool
EULER_SEQUENCE = "xyz"  # scipy's lower case: extrinsic axes


@dataclass(frozen=True)
class RegistrationConfig:
    """Registration settings; the defaults are what the bench reports."""

    reference_opening_rad: float = 0.15  # the canonical cloud's opening (mid-range)
    canonical_points: int = 1024  # model points, cloud -> model direction
    reverse_points: int = 128  # model points matched to the cloud (model -> cloud direction)
    articulated: bool = True  # estimate the hinge too; pose = leg a's frame
    n_roll: int = 4  # roll hypotheses about the principal axis (x2 signs), without a prior
    prior_roll_rad: float = 0.6  # with a prior: hypotheses turned up to this far either way about x
    prior_hypotheses: int = 3  # rolls of the prior, evenly spread over +-prior_roll_rad
    keep_hypotheses: int = 1  # best hypotheses per cloud carried through the fine iterations
    coarse_points: int = 64  # cloud (and reverse model) subsample for the hypotheses
    coarse_iterations: int = 6
    fine_iterations: int = 8  # voxel-grid nearest neighbours
    exact_iterations: int = 2  # k-d tree nearest neighbours, last
    trim_fraction: float = 0.0  # worst cloud -> model pairs left out of each SVD (trimming biases the
    # closed tweezer by millimetres and worsens the median rotation error on the bench clouds)
    reverse_trim_fraction: float = 0.25  # worst model -> cloud pairs left out (occluded model parts)
    reverse_weight: float = 0.0  # weight of the model -> cloud pairs relative to the cloud -> model ones
    grid_resolution_m: float = 0.0015
    grid_margin_m: float = 0.03

    def __post_init__(self):
        if self.n_roll < 1 or self.coarse_points < 8 or self.reverse_points < 8 or min(
                self.coarse_iterations, self.fine_iterations, self.exact_iterations) < 0:
            raise ConfigError(f"registration config out of range: {asdict(self)}")
        if not (0.0 <= self.trim_fraction < 0.5 and 0.0 <= self.reverse_trim_fraction < 0.8):
            raise ConfigError(f"trim fractions out of range: {self.trim_fraction}, {self.reverse_trim_fraction}")


@dataclass(frozen=True)
class TrackingConfig:
    """Tracking from a predicted pose (``CanonicalRegistration.track``); not part of the encoder's config.

    The motion prior adds ``(rotation_prior_m * phi)^2 + translation_prior * |d|^2`` to the mean
    squared point-to-plane residual (m^2), phi (rad) and d (m) the departure from the predicted
    pose: a rotation costs as much as moving the cloud by a lever arm of ``rotation_prior_m``
    times its angle. Against the tweezer's ~7 mm rms arm about its long axis and ~40 mm about
    the other two, 12 mm holds the roll (the noisy direction) and leaves pitch and yaw to the
    data; likewise 0.05 holds the slide along the legs (only the ~8% of points on faces across
    the legs see it) and leaves the other two directions to the data.
    The defaults are chosen on 3 mm / 20% clouds of a resting and of a moving tool: at rest the
    prior cuts the per-step rotation change to a fraction of frame-by-frame registration's
    (``analysis/bench/perception.md``, tracking at rest), and a tool turning at 0.5 rad/s about any
    axis and moving at 5 cm/s still gets omega and v close to the truth (mean over steps,
    tests/test_perception_tool_state.py). The price is lag: a sudden slide along the legs shows
    only in part in the first step (``analysis/perception/history/README.md``).
    """

    rotation_prior_m: float = 0.012
    translation_prior: float = 0.05  # dimensionless: against the mean squared point-to-plane residual
    predict_motion: float = 0.7  # fraction of the last step's motion carried into the prediction
    # (1: constant velocity, no lag but noisier at rest; 0: a tool at rest, the pose lags a moving tool)
    max_iterations: int = 3  # grid nearest neighbours from the warm start; later iterations only move
    # the pose within the grid's own noise
    tolerance_rad: float = 1e-3  # stop early when no tool's pose changed more than this in an iteration
    tolerance_m: float = 3e-5

    def __post_init__(self):
        if (min(self.rotation_prior_m, self.translation_prior, self.tolerance_rad, self.tolerance_m) < 0
                or not 0.0 <= self.predict_motion <= 1.0 or self.max_iterations < 1):
            raise ConfigError(f"tracking config out of range: {asdict(self)}")


@dataclass
class Registration:
    """Result for B clouds (leading axis dropped for a single cloud).

    rotation (B, 3, 3), translation (B, 3) m: tool frame -> hand_base; euler_xyz (B, 3) rad;
    hinge_angle (B,) rad, the opening estimated by articulated registration (NaN if rigid);
    rmse_m (B,): root mean square of the kept nearest-neighbour distances, metres.
    """

    rotation: np.ndarray
    translation: np.ndarray
    euler_xyz: np.ndarray
    hinge_angle: np.ndarray
    rmse_m: np.ndarray

    def to_tool_frame(self, clouds: np.ndarray) -> np.ndarray:
        """Clouds (B, N, 3) or (N, 3) in hand_base -> the tool frame: q = R^T (p - t)."""
        return (clouds - self.translation[..., None, :]) @ self.rotation


def check_clouds(clouds, min_points: int = MIN_POINTS) -> tuple[np.ndarray, bool]:
    """Validate clouds: (N, 3) or (B, N, 3), finite, N >= min_points. Returns ((B, N, 3) float64, single):
    a view of the caller's array when it is float64 already (callers read it, never write it)."""
    arr = np.asarray(clouds)
    if arr.ndim not in (2, 3) or arr.shape[-1] != 3:
        raise ConfigError(f"a tool cloud must have shape (N, 3) or (B, N, 3), got {arr.shape}")
    if arr.shape[-2] < min_points:
        raise ConfigError(f"a tool cloud has {arr.shape[-2]} points; at least {min_points} are needed "
                          "to register it (check the segmentation or the occlusion setting)")
    if not np.issubdtype(arr.dtype, np.number):
        raise ConfigError(f"a tool cloud must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    if not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).any(axis=-1).sum())
        raise ConfigError(f"a tool cloud has {bad} points with NaN or Inf coordinates; drop them before "
                          "registering (the camera pipeline's outlier removal does)")
    return (arr[None] if arr.ndim == 2 else arr), arr.ndim == 2


class _GridNearest:
    """Nearest model point by a precomputed voxel map: O(1) per query, approximate by <= one voxel.

    ``core`` is the map's block within ``CORE_MARGIN_M`` of the model's bounding box (``core_offset``:
    its first voxel): tracking looks cloud points up there and goes to the whole map only for a
    point outside it, the same voxels and answers. The whole map (~0.7 MB per leg at 1.5 mm with
    a 3 cm margin) falls out of the cache during the physics of every env step, and its misses
    cost a large share of a tracking step; the core (~0.1 MB) is what tracked points touch.
    """

    def __init__(self, points: np.ndarray, resolution: float, margin: float):
        self.points = points
        self.origin = points.min(axis=0) - margin
        self.resolution = resolution
        self.shape = np.ceil((points.max(axis=0) + margin - self.origin) / resolution).astype(int) + 1
        centres = (np.stack(np.meshgrid(*[np.arange(s) for s in self.shape], indexing="ij"), -1)
                   .reshape(-1, 3) + 0.5) * resolution + self.origin
        _, index = cKDTree(points).query(centres)
        # int16 where it fits: half the bytes of int32, fewer cache misses
        self.index = index.astype(np.int16 if len(points) <= np.iinfo(np.int16).max else np.int32).reshape(self.shape)
        core_margin = min(CORE_MARGIN_M, margin)
        self.core_margin = core_margin  # a point outside the core is farther than this from every model point
        low = np.floor((points.min(axis=0) - core_margin - self.origin) / resolution).astype(int)
        high = np.ceil((points.max(axis=0) + core_margin - self.origin) / resolution).astype(int) + 1
        low, high = np.maximum(low, 0), np.minimum(high, self.shape)
        self.core_offset = low.astype(np.int64)
        self.core = np.ascontiguousarray(self.index[low[0]:high[0], low[1]:high[1], low[2]:high[2]])

    def query(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cell = np.floor((q - self.origin) / self.resolution).astype(np.int64)
        np.clip(cell, 0, self.shape - 1, out=cell)
        idx = self.index[cell[..., 0], cell[..., 1], cell[..., 2]]
        return np.linalg.norm(q - self.points[idx], axis=-1), idx


class _TreeNearest:
    def __init__(self, points: np.ndarray):
        self.points = points
        self.tree = cKDTree(points)

    def query(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        flat = q.reshape(-1, 3)
        # threads pay off only on big batches (starting them costs more than a small query)
        dist, idx = self.tree.query(flat, workers=-1 if len(flat) > 20_000 else 1)
        return dist.reshape(q.shape[:-1]), idx.reshape(q.shape[:-1])


def kabsch(model: np.ndarray, observed: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best rigid motion with observed ~ R @ model + t, weighted, batched: (B, K, 3) x2, (B, K) -> R, t."""
    w = (weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-12))[:, None, :]  # (B, 1, K)
    mu_m = (w @ model)[:, 0]
    mu_o = (w @ observed)[:, 0]
    cov = np.swapaxes((model - mu_m[:, None]) * w[:, 0, :, None], 1, 2) @ (observed - mu_o[:, None])
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(np.swapaxes(vt, 1, 2) @ np.swapaxes(u, 1, 2)))
    fix = np.ones((len(d), 3))
    fix[:, 2] = d
    rot = np.swapaxes(vt, 1, 2) @ (fix[:, :, None] * np.swapaxes(u, 1, 2))
    return rot, mu_o - np.einsum("bij,bj->bi", rot, mu_m)


def _trim_weights(dist: np.ndarray, trim_fraction: float) -> np.ndarray:
    if trim_fraction <= 0:
        return np.ones_like(dist)
    k = int(np.floor((1 - trim_fraction) * dist.shape[1])) - 1
    cutoff = np.partition(dist, k, axis=1)[:, k:k + 1]
    return (dist <= cutoff).astype(float)


def _principal_frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (B, 3) and right-handed principal frames (B, 3, 3), columns by decreasing variance."""
    centre = points.mean(axis=1)
    x = points - centre[:, None]
    _, vecs = np.linalg.eigh(np.einsum("bni,bnj->bij", x, x))
    frames = vecs[:, :, ::-1].copy()
    frames[:, :, 2] = np.cross(frames[:, :, 0], frames[:, :, 1])
    return centre, frames


class CanonicalRegistration:
    """Registers tool clouds to the canonical cloud of a ``ToolGeometry`` (see the module docstring).

    ``register(clouds, prior=None)``: clouds (N, 3) or (B, N, 3) in hand_base; ``prior``
    an optional (R, t) (batched like the clouds) to start from (tracking) instead of the
    global hypotheses. Returns a ``Registration``.

    Each iteration pairs every cloud point with its nearest model point. With
    ``reverse_weight > 0`` a fixed subset of model points is also paired with its nearest
    cloud points (bidirectional ICP); on the bench clouds it does not help
    (more flips chosen, larger median error), so it is off by default.
    """

    def __init__(self, geometry: ToolGeometry | None = None, config: RegistrationConfig = RegistrationConfig()):
        self.geometry = geometry = geometry or ToolGeometry.default()
        self.config = c = config
        index = _even_subset(geometry.bank_part, c.canonical_points)
        self.canonical = geometry.surface_in_tool_frame(c.reference_opening_rad, index)
        part = geometry.bank_part[index]
        self.leg_a = self.canonical[part == 0]
        self.leg_b_local = geometry.bank_points[index][part == 1]  # leg b's own frame
        res, margin = c.grid_resolution_m, c.grid_margin_m
        self._grid_all = _GridNearest(self.canonical, res, margin)
        self._grid_a = _GridNearest(self.leg_a, res, margin)
        self._grid_b = _GridNearest(self.leg_b_local, res, margin)
        self._tree_all = _TreeNearest(self.canonical)
        self._tree_a, self._tree_b = _TreeNearest(self.leg_a), _TreeNearest(self.leg_b_local)
        self._canon_centre, self._canon_frame = _principal_frames(self.canonical[None])
        # the model subsets matched model -> cloud (fine and coarse), in part frames
        self._reverse = self._model_subset(c.reverse_points)
        self._reverse_coarse = self._model_subset(min(c.coarse_points, c.reverse_points))
        low, high = geometry.hinge_range
        self._hinge_bounds = (low - 0.05, high + 0.05)
        # the hinge axis and a point on it in the tool frame (leg b's pose at opening 0)
        rot0, pos0 = geometry.leg_b_pose(0.0)
        self._leg_b_zero = (rot0, pos0)
        self._axis = rot0 @ geometry._axis
        self._anchor = rot0 @ geometry._anchor + pos0
        # tracking's hinge update per leg-b model point (see _update_hinge): axis x m0 and m0 off the axis
        m0 = self.leg_b_local @ rot0.T + pos0 - self._anchor
        self._hinge_cross = np.cross(self._axis, m0)
        self._hinge_perp = m0 - np.outer(m0 @ self._axis, self._axis)
        self._skew = _skew(geometry._axis)
        self._normals = None  # tracking's model normals, made on first use
        self._cells = None  # exact nearest-neighbour cell lists of the compiled loops, made on first use
        self._tracking_arguments = None  # the tracking kernel's model arguments, made on first use
        self.compiled = True  # iterate in the compiled loops (registration_kernels); False: numpy (numpy_reference)

    def with_search(self, **changes) -> "CanonicalRegistration":
        """A copy sharing the precomputed model and maps, with other search settings
        (hypotheses, iterations, trimming; not the canonical cloud or the grids)."""
        fixed = {"reference_opening_rad", "canonical_points", "reverse_points", "coarse_points",
                 "grid_resolution_m", "grid_margin_m"}
        if fixed & set(changes):
            raise ConfigError(f"with_search cannot change {sorted(fixed & set(changes))}; make a new registration")
        other = copy.copy(self)
        other.config = replace(self.config, **changes)
        other._tracking_arguments = None  # they hold the trimming and articulation settings
        return other

    def numpy_reference(self) -> "CanonicalRegistration":
        """A copy that iterates in numpy, batched (the reference the compiled loops are tested
        against; also the path with ``reverse_weight > 0``, which the compiled loop does not do)."""
        other = copy.copy(self)
        other.compiled = False
        return other

    def _kernel_model(self) -> tuple:
        """The model arrays the compiled loops take, in their argument order."""
        if self._cells is None:
            c = self.config
            self._cells = tuple(registration_kernels.cell_lists(model, EXACT_CELL_M, c.grid_margin_m)
                                for model in (self.leg_a, self.leg_b_local))
        ga, gb = self._grid_a, self._grid_b
        return (self.leg_a, ga.index, ga.origin, self.leg_b_local, gb.index, gb.origin, float(ga.resolution),
                self._cells[0], self._cells[1], EXACT_CELL_M, self._hinge_cross, self._hinge_perp, self._anchor,
                self._skew, self.geometry._b_rot, self.geometry._b_pos, self.geometry._anchor,
                float(self._hinge_bounds[0]), float(self._hinge_bounds[1]), bool(self.config.articulated),
                float(self.config.reference_opening_rad), float(self.config.trim_fraction))

    def _iterate(self, points, rot, pos, theta, iterations: int, reverse, exact: bool):
        """``iterations`` ICP steps (``_step``) on C candidates: (rot, pos, theta, score)."""
        if self.compiled and self.config.reverse_weight == 0:
            return registration_kernels.icp_iterations(
                np.ascontiguousarray(points), np.ascontiguousarray(rot), np.ascontiguousarray(pos),
                np.ascontiguousarray(theta, dtype=float), int(iterations), bool(exact), *self._kernel_model())
        score = None
        for _ in range(iterations):
            rot, pos, theta, score = self._step(points, rot, pos, theta, reverse, exact)
        return rot, pos, theta, score

    def _model_subset(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(points (n, 3) in their part frames, is_leg_b (n,)) spread evenly over both parts."""
        index = _even_subset(self.geometry.bank_part, n)
        return self.geometry.bank_points[index], self.geometry.bank_part[index] == 1

    # ------------------------------------------------------------------ public
    def register(self, clouds, prior: tuple[np.ndarray, np.ndarray] | None = None,
                 hinge_prior=None) -> Registration:
        """Register clouds; ``prior`` (R, t) a pose to start from, ``hinge_prior`` (rad, scalar
        or (B,)) an opening to start from (default: the reference opening). Tracking passes
        the previous frame's pose and opening."""
        points, single = check_clouds(clouds)
        c = self.config
        n_batch = len(points)
        if prior is not None:
            prior = (np.broadcast_to(np.asarray(prior[0], float), (n_batch, 3, 3)).copy(),
                     np.broadcast_to(np.asarray(prior[1], float), (n_batch, 3)).copy())
            _check_prior(*prior)
        start = np.broadcast_to(np.asarray(c.reference_opening_rad if hinge_prior is None else hinge_prior,
                                           float), (n_batch,))
        if not np.isfinite(start).all():
            raise ConfigError("the hinge prior for registration has NaN or Inf; pass hinge_prior=None")
        rot, pos, theta, n_keep = self._hypotheses(points, prior, np.clip(start, *self._hinge_bounds))
        candidates = np.repeat(points, n_keep, axis=0)
        rot, pos, theta, score = self._iterate(candidates, rot, pos, theta, c.fine_iterations, self._reverse,
                                               exact=False)
        if n_keep > 1:  # each cloud's best surviving hypothesis
            best = np.argmin(score.reshape(n_batch, n_keep), axis=1) + np.arange(n_batch) * n_keep
            rot, pos, theta = rot[best], pos[best], theta[best]
        rot, pos, theta, score = self._iterate(points, rot, pos, theta, c.exact_iterations, self._reverse, exact=True)
        # the residual of the last iteration's pairs (before its small final update)
        rmse = np.sqrt(score) if c.exact_iterations and c.reverse_weight == 0 else self._forward_rmse(
            points, rot, pos, theta)
        result = Registration(rot, pos, euler_xyz(rot), theta if c.articulated else np.full(n_batch, np.nan), rmse)
        if single:
            result = Registration(*(getattr(result, f)[0] for f in result.__dataclass_fields__))
        return result

    def track(self, clouds, rotation, translation, hinge, config: TrackingConfig = TrackingConfig()
              ) -> Registration:
        """Register clouds (B, N, 3) near predicted poses: ICP with a motion prior (module docstring).

        ``rotation`` (B, 3, 3), ``translation`` (B, 3) m: the predicted pose, hand_base, both the
        start and the prior's centre; ``hinge`` (B,) rad: the previous opening (the start).
        Each iteration pairs the cloud with its nearest model points (grid lookups) and takes
        one Gauss-Newton step on the point-to-plane residuals plus the prior (a 6x6 solve):
        point-to-plane, because point-to-point ICP slides along the long thin legs only a
        fraction of the way per iteration, which a warm start with few iterations would turn
        into lag. Iterates until no tool moved more than the tolerances. ``rmse_m``: the
        last pairs' point-to-point residual.

        Runs the compiled loop (``hingelab.perception.registration_kernels``, the same arithmetic;
        each tool stops iterating on its own); ``numpy_reference().track`` is this loop in numpy.
        """
        if not self.compiled:
            return self._track_numpy(clouds, rotation, translation, hinge, config)
        points, single = check_clouds(clouds)
        rot_p, pos_p, theta = self._track_start(points, rotation, translation, hinge)
        rot, pos, theta, score, euler, locked = registration_kernels.track_batch(
            points, rot_p, pos_p, theta, *self.tracking_arguments(), *tracking_settings(config))
        if locked.any():  # near gimbal lock: scipy's convention (as euler_xyz)
            euler[locked] = Rotation.from_matrix(rot[locked]).as_euler(EULER_SEQUENCE)
        return self._tracked(rot, pos, theta, score, single, euler)

    def tracking_arguments(self) -> tuple:
        """The model arrays and settings ``registration_kernels.track_batch`` takes, in its argument
        order (made once: assembling them is a noticeable share of a tracking step)."""
        if self._tracking_arguments is None:
            normals_a, normals_b = self._model_normals()
            ga, gb = self._grid_a, self._grid_b
            c = self.config
            self._tracking_arguments = (
                self.leg_a, normals_a, ga.index, ga.origin, ga.core, ga.core_offset, self.leg_b_local, normals_b,
                gb.index, gb.origin, gb.core, gb.core_offset, float(ga.resolution),
                min(ga.core_margin, gb.core_margin) - 1e-9,  # a nanometre less: rounding at the blocks' edges
                self._hinge_cross, self._hinge_perp, self._anchor, self._skew, self.geometry._b_rot,
                self.geometry._b_pos, self.geometry._anchor, float(self._hinge_bounds[0]),
                float(self._hinge_bounds[1]), bool(c.articulated), float(c.trim_fraction))
        return self._tracking_arguments

    def _track_start(self, points, rotation, translation, hinge):
        n_batch = len(points)
        rot_p = _batch_copy(rotation, (n_batch, 3, 3))
        pos_p = _batch_copy(translation, (n_batch, 3))
        _check_prior(rot_p, pos_p)
        low, high = self._hinge_bounds
        # np.clip's dispatch cost more than the arithmetic here (a step's B is 1)
        theta = np.minimum(np.maximum(_batch_copy(hinge, (n_batch,)), low), high)
        return rot_p, pos_p, theta

    def _tracked(self, rot, pos, theta, score, single: bool, euler=None) -> Registration:
        result = Registration(rot, pos, euler_xyz(rot) if euler is None else euler,
                              theta if self.config.articulated else np.full(len(rot), np.nan), np.sqrt(score))
        if single:
            result = Registration(*(getattr(result, f)[0] for f in result.__dataclass_fields__))
        return result

    def _track_numpy(self, clouds, rotation, translation, hinge, config: TrackingConfig) -> Registration:
        """``track`` in numpy, batched: the whole batch iterates until no tool moves."""
        points, single = check_clouds(clouds)
        c = self.config
        rot_p, pos_p, theta = self._track_start(points, rotation, translation, hinge)
        normals_a, normals_b = self._model_normals()
        k_r, k_t = config.rotation_prior_m ** 2, config.translation_prior
        rot, pos = rot_p, pos_p
        for _ in range(config.max_iterations):
            rot_b, pos_b = self._leg_b_fast(theta)
            local = (points - pos[:, None]) @ rot  # tool frame
            dist_a, index_a = self._grid_a.query(local)
            dist_b, index_b = self._grid_b.query((local - pos_b[:, None]) @ rot_b)
            on_b = dist_b < dist_a
            model = np.where(on_b[..., None], self.leg_b_local[index_b] @ np.swapaxes(rot_b, 1, 2) + pos_b[:, None],
                             self.leg_a[index_a])
            normal = np.where(on_b[..., None], normals_b[index_b] @ np.swapaxes(rot_b, 1, 2), normals_a[index_a])
            dist = np.where(on_b, dist_b, dist_a)
            w = _trim_weights(dist, c.trim_fraction)
            w = w / w.sum(axis=1, keepdims=True)
            score = (w * dist ** 2).sum(axis=1)
            omega, turn, new_pos = _plane_step(points, model @ np.swapaxes(rot, 1, 2) + pos[:, None],
                                               normal @ np.swapaxes(rot, 1, 2), w, rot, pos, rot_p, pos_p, k_r, k_t)
            rot = turn @ rot
            moved = np.abs(new_pos - pos).max()
            pos = new_pos
            if c.articulated:
                theta = self._track_hinge(points, rot, pos, theta, index_b, w * on_b)
            if np.abs(omega).max() < config.tolerance_rad and moved < config.tolerance_m:
                break
        return self._tracked(rot, pos, theta, score, single)

    def _model_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """Surface normals of leg a's (tool frame) and leg b's (own frame) model points, by PCA
        over the bank's points of the same part within 2.5 mm (at least the 5 nearest); signless."""
        if self._normals is None:
            out = []
            for model, part in ((self.leg_a, 0), (self.leg_b_local, 1)):
                bank = self.geometry.bank_points[self.geometry.bank_part == part]  # the part's own frame
                dist, index = cKDTree(bank).query(model, k=12)
                near = ((dist < 0.0025) | (np.arange(12) < 5))[..., None]
                neighbours = bank[index]
                centre = (near * neighbours).sum(1) / near.sum(1)
                spread = (neighbours - centre[:, None]) * near
                _, vectors = np.linalg.eigh(np.einsum("mki,mkj->mij", spread, spread))
                out.append(vectors[:, :, 0])
            self._normals = tuple(out)
        return self._normals

    def _leg_b_fast(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``geometry.leg_b_pose`` by Rodrigues' formula (no scipy objects in the tracking loop)."""
        g = self.geometry
        s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
        hinge_rot = np.eye(3) + s * self._skew + (1 - c) * (self._skew @ self._skew)
        rot = g._b_rot @ hinge_rot
        pos = g._b_rot @ g._anchor + g._b_pos - rot @ g._anchor
        return rot, pos

    def _track_hinge(self, points, rot, pos, theta, index_b, weights):
        """``_update_hinge`` with the per-model-point vectors precomputed: the same 2-D Procrustes."""
        q = (points - pos[:, None]) @ rot - self._anchor
        cross = (weights * np.einsum("bni,bni->bn", q, self._hinge_cross[index_b])).sum(axis=1)
        dot = (weights * np.einsum("bni,bni->bn", q, self._hinge_perp[index_b])).sum(axis=1)
        has_b = (weights > 0).sum(axis=1) >= 3
        return np.where(has_b, np.clip(np.arctan2(cross, dot), *self._hinge_bounds), theta)

    # ------------------------------------------------------------------ stages
    def _hypotheses(self, points: np.ndarray, prior, hinge_start: np.ndarray):
        """Start poses, a few coarse iterations each on a subsample; returns the best
        ``keep_hypotheses`` per cloud: (rot, pos, theta, k).

        Without a prior: 2 * n_roll principal-axis hypotheses (both signs of the long axis,
        rolls about it). With a prior (R, t): the prior turned by -prior_roll, 0, +prior_roll
        about the tool's long axis (x), the axis along which point-to-point ICP turns slowest.
        The cloud's centroid places every hypothesis (a prior's translation may be centimetres off).
        """
        c = self.config
        n_batch, n_points = points.shape[:2]
        centre, frames = _principal_frames(points)
        if prior is None:
            hypotheses = []
            for sign in (1.0, -1.0):
                flip = np.diag([sign, sign, 1.0])  # 180 degrees about the third axis: stays right-handed
                for k in range(c.n_roll):
                    hypotheses.append(flip @ Rotation.from_rotvec([2 * np.pi * k / c.n_roll, 0, 0]).as_matrix())
            hyp = np.stack(hypotheses)  # (H, 3, 3), in principal-frame coordinates
            # R maps the canonical principal frame onto the cloud's: R = E H F^T
            rot = np.einsum("bij,hjk,kl->bhil", frames, hyp, self._canon_frame[0].T).reshape(-1, 3, 3)
        else:
            rolls = Rotation.from_rotvec(np.outer(np.linspace(-1.0, 1.0, c.prior_hypotheses) * c.prior_roll_rad,
                                                  [1, 0, 0]))
            hyp = rolls.as_matrix()
            rot = (prior[0][:, None] @ hyp[None]).reshape(-1, 3, 3)
        n_hyp = len(hyp)
        pos = np.repeat(centre, n_hyp, axis=0) - rot @ self._canon_centre[0]
        theta = np.repeat(hinge_start, n_hyp)
        if n_hyp == 1:  # tracking: nothing to choose between
            return rot, pos, theta, 1
        sub = points[:, np.linspace(0, n_points - 1, min(c.coarse_points, n_points)).astype(int)]
        sub = np.repeat(sub, n_hyp, axis=0)
        rot, pos, theta, score = self._iterate(sub, rot, pos, theta, max(c.coarse_iterations, 1),
                                               self._reverse_coarse, exact=False)
        n_keep = min(c.keep_hypotheses, n_hyp)
        keep = (np.argsort(score.reshape(n_batch, n_hyp), axis=1)[:, :n_keep]
                + np.arange(n_batch)[:, None] * n_hyp).ravel()
        return rot[keep], pos[keep], theta[keep], n_keep

    def _leg_b(self, theta):
        if self.config.articulated:
            return self.geometry.leg_b_pose(theta)
        rot, pos = self.geometry.leg_b_pose(np.full(len(theta), self.config.reference_opening_rad))
        return rot, pos

    def _forward(self, local, rot_b, pos_b, exact: bool):
        """Cloud (tool frame, (C, N, 3)) -> nearest model point: (model (C, N, 3), dist, on_b, leg-b index)."""
        local_b = (local - pos_b[:, None]) @ rot_b  # leg b's frame
        near_a, near_b = (self._tree_a, self._tree_b) if exact else (self._grid_a, self._grid_b)
        da, ia = near_a.query(local)
        db, ib = near_b.query(local_b)
        on_b = db < da
        model_b = self.leg_b_local[ib] @ np.swapaxes(rot_b, 1, 2) + pos_b[:, None]
        return np.where(on_b[..., None], model_b, self.leg_a[ia]), np.where(on_b, db, da), on_b, ib

    def _forward_rmse(self, points, rot, pos, theta) -> np.ndarray:
        local = (points - pos[:, None]) @ rot
        _, dist, _, _ = self._forward(local, *self._leg_b(theta), exact=True)
        w = _trim_weights(dist, self.config.trim_fraction)
        return np.sqrt((w * dist ** 2).sum(axis=1) / np.maximum(w.sum(axis=1), 1))

    def _step(self, points, rot, pos, theta, reverse, exact: bool):
        """One ICP iteration on C candidates: (rot, pos, theta, score (C,)).

        score: mean squared distance of the kept pairs (both directions if reverse_weight > 0),
        before the update.
        """
        c = self.config
        rot_b, pos_b = self._leg_b(theta)
        local = (points - pos[:, None]) @ rot  # tool frame
        model_f, dist_f, on_b_f, ib = self._forward(local, rot_b, pos_b, exact)
        w_f = _trim_weights(dist_f, c.trim_fraction)
        score = (w_f * dist_f ** 2).sum(1) / w_f.sum(1)
        model, observed, weights = model_f, points, w_f
        leg_b_local, leg_b_weights = self.leg_b_local[ib], w_f * on_b_f
        if c.reverse_weight > 0:
            model_r, observed_r, w_r, rev_score = self._reverse_pairs(points, local, rot_b, pos_b, reverse)
            score = score + rev_score
            # the two directions weigh reverse_weight : 1 in the SVD, whatever their point counts
            scale = c.reverse_weight * points.shape[1] / len(reverse[0])
            model = np.concatenate([model_f, model_r], 1)
            observed = np.concatenate([points, observed_r], 1)
            weights = np.concatenate([w_f, scale * w_r], 1)
            leg_b_local = np.concatenate([leg_b_local, reverse[0][None].repeat(len(points), 0)], 1)
            leg_b_weights = np.concatenate([leg_b_weights, scale * w_r * reverse[1]], 1)
        rot, pos = kabsch(model, observed, weights)
        if c.articulated:
            theta = self._update_hinge(rot, pos, theta, leg_b_local,
                                       observed if c.reverse_weight > 0 else points, leg_b_weights)
        return rot, pos, theta, score

    def _reverse_pairs(self, points, local, rot_b, pos_b, reverse):
        """Model subset -> nearest cloud point, brute force (C x M x N is small): model, observed, w, score."""
        rev_local, rev_on_b = reverse
        model_r = np.where(rev_on_b[:, None], rev_local @ np.swapaxes(rot_b, 1, 2) + pos_b[:, None],
                           rev_local)
        d2 = (np.einsum("bmi,bmi->bm", model_r, model_r)[:, :, None]
              + np.einsum("bni,bni->bn", local, local)[:, None, :]
              - 2 * (model_r @ np.swapaxes(local, 1, 2)))
        nearest = np.argmin(d2, axis=2)
        dist_r = np.sqrt(np.maximum(np.take_along_axis(d2, nearest[..., None], 2)[..., 0], 0))
        w_r = _trim_weights(dist_r, self.config.reverse_trim_fraction)
        observed_r = np.take_along_axis(points, nearest[..., None], 1)
        return model_r, observed_r, w_r, (w_r * dist_r ** 2).sum(1) / w_r.sum(1)

    def _update_hinge(self, rot, pos, theta, leg_b_local, observed, weights):
        """Hinge angle that turns leg b's matched points (at opening 0) about the hinge axis
        onto the observed points, both in the new tool frame (2-D Procrustes), clipped."""
        rot0, pos0 = self._leg_b_zero
        m0 = leg_b_local @ rot0.T + pos0 - self._anchor
        q = (observed - pos[:, None]) @ rot - self._anchor
        axis = self._axis
        cross = (weights * (np.cross(m0, q) @ axis)).sum(axis=1)
        # dot product of the components perpendicular to the axis
        dot = (weights * ((m0 * q).sum(axis=2) - (m0 @ axis) * (q @ axis))).sum(axis=1)
        has_b = (weights > 0).sum(axis=1) >= 3
        return np.where(has_b, np.clip(np.arctan2(cross, dot), *self._hinge_bounds), theta)


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices: (..., 3) -> (..., 3, 3) with _skew(a) @ b = a x b."""
    v = np.asarray(v, float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, (B, 3) -> (B, 3, 3) (scipy's ``from_rotvec``, without its per-call cost;
    compiled: ``pose_kernels``)."""
    return pose_kernels.rotvecs_to_matrices(np.ascontiguousarray(rotvec, dtype=float))


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """Rotation vectors (B, 3) of rotations (B, 3, 3): scipy's ``as_rotvec``, in closed form for
    the frame-to-frame turns it is used on (compiled: ``pose_kernels``); turns within ~0.6 degrees
    of 180 go to scipy."""
    rot = np.ascontiguousarray(rot, dtype=float)
    out, near_pi = pose_kernels.matrices_to_rotvecs(rot)
    if near_pi.any():
        out[near_pi] = Rotation.from_matrix(rot[near_pi]).as_rotvec()
    return out


def _plane_step(points, model, normals, w, rot, pos, rot_p, pos_p, k_r: float, k_t: float):
    """One Gauss-Newton step of point-to-plane ICP with a motion prior, batched; all in hand_base.

    points, model, normals (B, N, 3): the pairs and the model normals; w (B, N) weights summing to 1;
    (rot, pos) the current pose, (rot_p, pos_p) the prior's. The step turns the tool by omega about
    the cloud's centroid c and shifts it by tau; it minimizes
    sum w (n . (p - m - omega x (m - c) - tau))^2 + k_r |omega + e_r|^2 + k_t |t' - t_p|^2,
    e_r the current rotation's departure from the prior's (rotation vector), t' the new origin.
    Returns (omega (B, 3), its rotation matrix (B, 3, 3), new translation (B, 3)).
    """
    centre = np.einsum("bn,bni->bi", w, points)
    jac = np.concatenate([np.cross(model - centre[:, None], normals), normals], axis=2)  # (B, N, 6)
    residual = np.einsum("bni,bni->bn", points - model, normals)
    hess = np.swapaxes(jac, 1, 2) @ (w[..., None] * jac)
    grad = np.einsum("bni,bn->bi", jac, w * residual)
    # prior: the rotation's departure (small-angle log of R R_p^T) and the new origin's, linear in (omega, tau)
    rel = rot @ np.swapaxes(rot_p, 1, 2)
    e_r = 0.5 * np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1)
    lever = np.concatenate([-_skew(pos - centre), np.broadcast_to(np.eye(3), (len(pos), 3, 3))], axis=2)  # (B, 3, 6)
    hess = hess + k_t * np.swapaxes(lever, 1, 2) @ lever
    hess[:, :3, :3] += k_r * np.eye(3)
    hess += 1e-12 * np.eye(6)  # a degenerate cloud without a prior: no step along the unseen directions
    grad = grad - k_t * np.einsum("bki,bk->bi", lever, pos - pos_p)
    grad[:, :3] -= k_r * e_r
    step = np.linalg.solve(hess, grad[..., None])[..., 0]
    omega, tau = step[:, :3], step[:, 3:]
    turn = rotvec_to_matrix(omega)
    return omega, turn, centre + np.einsum("bij,bj->bi", turn, pos - centre) + tau


def _batch_copy(value, shape: tuple) -> np.ndarray:
    """A float64 copy of ``value`` in ``shape``, broadcast if it has another (np.broadcast_to costs
    several times a plain copy: tracking's inputs have the batch's shape already)."""
    arr = np.array(value, dtype=float)
    return arr if arr.shape == shape else np.broadcast_to(arr, shape).copy()


@functools.cache
def tracking_settings(config: TrackingConfig) -> tuple:
    """The tracking config as ``registration_kernels.track_batch``'s last arguments."""
    return (float(config.rotation_prior_m ** 2), float(config.translation_prior), int(config.max_iterations),
            float(config.tolerance_rad), float(config.tolerance_m))


def _check_prior(rot: np.ndarray, pos: np.ndarray) -> None:
    finite, orthonormality = pose_kernels.pose_check(np.ascontiguousarray(rot, dtype=float),
                                                     np.ascontiguousarray(pos, dtype=float))
    if not finite:
        raise ConfigError("the prior pose for registration has NaN or Inf; pass prior=None for a global start")
    if orthonormality > pose_kernels.ORTHONORMALITY_TOLERANCE:
        raise ConfigError("the prior rotation for registration is not a rotation matrix (R R^T != I)")


def euler_xyz(rot: np.ndarray) -> np.ndarray:
    """Extrinsic x-y-z Euler angles (rad) of rotations (B, 3, 3): scipy's ``as_euler("xyz")``,
    in closed form (a scipy Rotation's per-call cost is a sizeable share of a tracking step;
    compiled: ``pose_kernels``); near gimbal lock (pitch within ~0.8 degrees of +-90) scipy's
    convention is used."""
    rot = np.ascontiguousarray(rot, dtype=float)
    out, locked = pose_kernels.euler_angles_xyz(rot)
    if locked.any():
        out[locked] = Rotation.from_matrix(rot[locked]).as_euler(EULER_SEQUENCE)
    return out


def rotation_error_rad(rot_est: np.ndarray, rot_true: np.ndarray) -> np.ndarray:
    """Angle of R_est^T R_true, radians: (..., 3, 3) x2 -> (...)."""
    rel = np.einsum("...ji,...jk->...ik", rot_est, rot_true)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1) / 2
    return np.arccos(np.clip(cos, -1.0, 1.0))


__all__ = ["CanonicalRegistration", "MIN_POINTS", "Registration", "RegistrationConfig", "TrackingConfig",
           "check_clouds", "euler_xyz", "kabsch", "matrix_to_rotvec", "rotation_error_rad", "rotvec_to_matrix"]
