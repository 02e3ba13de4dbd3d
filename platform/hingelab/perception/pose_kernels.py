"""Small pose arithmetic that runs every env step, compiled (numba).

An env step turns one cloud into a tool state: a handful of 3x3 rotations, a 256-point
transform, a mean over 256 displacements. In numpy each of these is a chain of ~10 array
operations on tiny arrays, and the per-operation cost (a few microseconds) summed to ~0.3 ms
per step, a quarter of the step's physics. These kernels do the same formulas in plain loops
(the callers in ``registration``, ``clouds`` and ``envs.rewards`` keep their numpy contracts;
tests hold them to scipy and to the numpy formulas). Cached on disk like the registration
kernels (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def rotvecs_to_matrices(rotvec):
    """Rodrigues' formula: (B, 3) -> (B, 3, 3); angles below 1e-8 take the series' limits."""
    n = rotvec.shape[0]
    out = np.empty((n, 3, 3))
    for b in range(n):
        x, y, z = rotvec[b, 0], rotvec[b, 1], rotvec[b, 2]
        angle = np.sqrt(x * x + y * y + z * z)
        if angle < 1e-8:
            s, c = 1.0, 0.5
        else:
            s, c = np.sin(angle) / angle, (1.0 - np.cos(angle)) / (angle * angle)
        # I + s K + c K^2, K the cross-product matrix of (x, y, z)
        out[b, 0, 0] = 1.0 - c * (y * y + z * z)
        out[b, 1, 1] = 1.0 - c * (x * x + z * z)
        out[b, 2, 2] = 1.0 - c * (x * x + y * y)
        out[b, 0, 1] = -s * z + c * x * y
        out[b, 1, 0] = s * z + c * x * y
        out[b, 0, 2] = s * y + c * x * z
        out[b, 2, 0] = -s * y + c * x * z
        out[b, 1, 2] = -s * x + c * y * z
        out[b, 2, 1] = s * x + c * y * z
    return out


@njit(cache=True)
def matrices_to_rotvecs(rot):
    """(B, 3, 3) -> (rotation vectors (B, 3), near_pi (B,) bool): the closed form, exact away
    from 180 degrees; rows flagged near_pi (cos < -0.99995) are for the caller to redo."""
    n = rot.shape[0]
    out = np.empty((n, 3))
    near_pi = np.zeros(n, np.bool_)
    for b in range(n):
        cos = min(max((rot[b, 0, 0] + rot[b, 1, 1] + rot[b, 2, 2] - 1.0) / 2.0, -1.0), 1.0)
        angle = np.arccos(cos)
        if angle < 1e-4:  # angle / (2 sin angle) -> 1/2 + angle^2 / 12
            factor = 0.5 + angle * angle / 12.0
        else:
            factor = angle / (2.0 * np.sin(angle))
        out[b, 0] = factor * (rot[b, 2, 1] - rot[b, 1, 2])
        out[b, 1] = factor * (rot[b, 0, 2] - rot[b, 2, 0])
        out[b, 2] = factor * (rot[b, 1, 0] - rot[b, 0, 1])
        near_pi[b] = cos < -0.99995
    return out, near_pi


@njit(cache=True)
def euler_angles_xyz(rot):
    """(B, 3, 3) -> (extrinsic x-y-z angles (B, 3), locked (B,) bool: within ~0.8 degrees of
    gimbal lock, for the caller to redo in scipy's convention)."""
    n = rot.shape[0]
    out = np.empty((n, 3))
    locked = np.zeros(n, np.bool_)
    for b in range(n):
        out[b, 0] = np.arctan2(rot[b, 2, 1], rot[b, 2, 2])
        out[b, 1] = np.arcsin(min(max(-rot[b, 2, 0], -1.0), 1.0))
        out[b, 2] = np.arctan2(rot[b, 1, 0], rot[b, 0, 0])
        locked[b] = abs(rot[b, 2, 0]) > 0.9999
    return out, locked


@njit(cache=True)
def pose_check(rot, pos):
    """(all finite, max |R R^T - I| over the batch) of rotations (B, 3, 3) and positions (B, 3)."""
    finite = np.isfinite(rot).all() and np.isfinite(pos).all()
    worst = 0.0
    for b in range(rot.shape[0]):
        for i in range(3):
            for k in range(3):
                dot = rot[b, i, 0] * rot[b, k, 0] + rot[b, i, 1] * rot[b, k, 1] + rot[b, i, 2] * rot[b, k, 2]
                worst = max(worst, abs(dot - (1.0 if i == k else 0.0)))
    return finite, worst


@njit(cache=True)
def mean_displacement(points, rot, shift):
    """Mean over points (N, 3) of ||R p + shift - p||."""
    total = 0.0
    for i in range(points.shape[0]):
        sq = 0.0
        for k in range(3):
            moved = rot[k, 0] * points[i, 0] + rot[k, 1] * points[i, 1] + rot[k, 2] * points[i, 2] + shift[k]
            sq += (moved - points[i, k]) ** 2
        total += np.sqrt(sq)
    return total / points.shape[0]


@njit(cache=True)
def place_parts(local, on_b, rot_a, pos_a, rot_b, pos_b):
    """Part-frame points (B, n, 3) into hand_base: R p + t of leg b where on_b (B, n), else of leg a."""
    n_batch, n = local.shape[0], local.shape[1]
    out = np.empty((n_batch, n, 3))
    for b in range(n_batch):
        for i in range(n):
            rot, pos = (rot_b[b], pos_b[b]) if on_b[b, i] else (rot_a[b], pos_a[b])
            for k in range(3):
                out[b, i, k] = rot[k, 0] * local[b, i, 0] + rot[k, 1] * local[b, i, 1] + \
                    rot[k, 2] * local[b, i, 2] + pos[k]
    return out


__all__ = ["euler_angles_xyz", "matrices_to_rotvecs", "mean_displacement", "place_parts", "pose_check",
           "rotvecs_to_matrices"]
