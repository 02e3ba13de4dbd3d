"""How the simulated depth camera departs from the rendered depth: noise and missing returns.

A time-of-flight camera such as the Azure Kinect DK (the model's defaults below):

* **axial noise growing with range**: Gaussian, std ``sigma(z) = base + quadratic * z**2``;
  the defaults give 1.3 mm at the rig's 0.6 m and 14 mm at 3 m, inside the Azure Kinect DK
  specification's random-error bound (std <= 17 mm over its range, confirmed by Tolgyessy
  et al., "Evaluation of the Azure Kinect and its comparison to Kinect V1 and Kinect V2",
  Sensors 21(2):413, 2021). The quadratic growth is the usual model for ToF and structured-light
  depth; its two coefficients are chosen, not fitted to a unit;
* **missing pixels at grazing angles**: a surface seen at incidence angle a (between its
  normal, from the depth image's gradients, and the ray) is lost with probability rising
  linearly from 0 at ``grazing_start_deg`` to 1 at ``grazing_end_deg``;
* **missing pixels at edges**: a pixel whose depth differs from a 4-neighbour's by more than
  ``edge_jump_m`` (a silhouette: mixed returns, the "flying pixels" the camera invalidates) is
  lost with probability ``edge_drop``;
* **random dropout** of ``dropout`` of the remaining pixels.

Missing pixels read 0, as the camera reports them. ``NO_NOISE`` turns all of it off.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from hingelab.camera import DepthIntrinsics
from hingelab.errors import ConfigError


@dataclass(frozen=True)
class DepthNoise:
    base_m: float = 0.0008  # axial std at zero range
    quadratic_m_per_m2: float = 0.0015  # axial std growth with range squared
    grazing_start_deg: float = 70.0
    grazing_end_deg: float = 85.0
    edge_jump_m: float = 0.01
    edge_drop: float = 0.6
    dropout: float = 0.005

    def __post_init__(self):
        if min(self.base_m, self.quadratic_m_per_m2, self.edge_jump_m) < 0:
            raise ConfigError(f"depth noise values must be >= 0: {asdict(self)}")
        if not 0 <= self.grazing_start_deg < self.grazing_end_deg <= 90:
            raise ConfigError(f"grazing angles must satisfy 0 <= start < end <= 90: {asdict(self)}")
        if not (0 <= self.edge_drop <= 1 and 0 <= self.dropout < 1):
            raise ConfigError(f"edge_drop must be in [0, 1] and dropout in [0, 1): {asdict(self)}")

    def to_json(self) -> dict:
        return asdict(self)

    def apply(self, depth: np.ndarray, intrinsics: DepthIntrinsics, rng: np.random.Generator) -> np.ndarray:
        """A noisy copy of ``depth`` (H, W) m (0 = no return)."""
        depth = np.asarray(depth, np.float32)
        p_kept = np.full(depth.shape, 1.0 - self.dropout, np.float32)
        if self.edge_drop > 0:
            p_kept *= np.where(silhouette(depth, self.edge_jump_m), np.float32(1.0 - self.edge_drop), np.float32(1.0))
        if self.grazing_end_deg < 90:
            angle = incidence_angle_deg(depth, intrinsics)
            p_kept *= 1.0 - np.clip((angle - self.grazing_start_deg) / (self.grazing_end_deg - self.grazing_start_deg),
                                    0.0, 1.0)
        # one uniform and one normal draw per pixel, whatever is switched on: the draws stay aligned
        keep = (rng.random(depth.shape, dtype=np.float32) < p_kept) & (depth > 0)
        sigma = self.base_m + self.quadratic_m_per_m2 * depth * depth
        noisy = depth + sigma * rng.standard_normal(depth.shape, dtype=np.float32)
        return np.where(keep & (noisy > 0), noisy, np.float32(0.0)).astype(np.float32)


NO_NOISE = DepthNoise(0.0, 0.0, 89.0, 90.0, 0.0, 0.0, 0.0)


def silhouette(depth: np.ndarray, jump_m: float) -> np.ndarray:
    """(H, W) bool: valid pixels whose depth differs from a 4-neighbour's by more than ``jump_m`` (or borders a
    hole)."""
    d = np.where(depth > 0, depth, np.float32(1e6))  # a hole next to a pixel counts as a jump
    edge = np.zeros(depth.shape, bool)
    dy = np.abs(d[1:] - d[:-1]) > jump_m
    dx = np.abs(d[:, 1:] - d[:, :-1]) > jump_m
    edge[1:] |= dy
    edge[:-1] |= dy
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    return edge & (depth > 0)


def incidence_angle_deg(depth: np.ndarray, intrinsics: DepthIntrinsics) -> np.ndarray:
    """(H, W): the angle between each pixel's surface normal (from central differences) and its ray; 0 where unknown."""
    k = intrinsics
    depth = np.asarray(depth, np.float32)
    h, w = depth.shape
    rx = ((np.arange(w, dtype=np.float32) - k.cx) / k.fx)[None, :]  # the ray through each pixel: (rx, ry, 1)
    ry = ((np.arange(h, dtype=np.float32) - k.cy) / k.fy)[:, None]
    x, y = rx * depth, ry * depth
    # central differences of the back-projected points along u (columns) and v (rows); borders stay 0
    ux, uy, uz = (np.zeros_like(depth) for _ in range(3))
    vx, vy, vz = (np.zeros_like(depth) for _ in range(3))
    ux[:, 1:-1], uy[:, 1:-1], uz[:, 1:-1] = x[:, 2:] - x[:, :-2], y[:, 2:] - y[:, :-2], depth[:, 2:] - depth[:, :-2]
    vx[1:-1], vy[1:-1], vz[1:-1] = x[2:] - x[:-2], y[2:] - y[:-2], depth[2:] - depth[:-2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    dot = nx * rx + ny * ry + nz
    norm = np.sqrt((nx * nx + ny * ny + nz * nz) * (rx * rx + ry * ry + 1.0))
    cos = np.abs(dot) / np.where(norm > 0, norm, np.float32(1.0))
    return np.where(norm > 0, np.degrees(np.arccos(np.minimum(cos, 1.0))), np.float32(0.0)).astype(np.float32)
