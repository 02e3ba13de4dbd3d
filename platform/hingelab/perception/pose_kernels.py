"""Small pose arithmetic that runs every env step, compiled (numba).

An env step turns one cloud into a tool state: a handful of 3x3 rotations, a 256-point
transform, a mean over 256 displacements. In numpy each of these is a chain of ~10 array
operations on tiny arrays, and the per-operation cost (a few microseconds) sums to a sizeable
share of the step's physics. These kernels do the same formulas in plain loops
(the callers in ``registration``, ``clouds`` and ``envs.rewards`` keep their numpy contracts;
tests hold them to scipy and to the numpy formulas). Cached on disk like the registration
kernels (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

ORTHONORMALITY_TOLERANCE = 1e-3  # max |R R^T - I| of a rotation matrix (pose_check's second value)


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
def hand_frame_poses(xmat, xpos, hand, bodies):
    """Poses of ``bodies`` in the hand's frame from MjData's world poses (xmat (nbody, 9), xpos
    (nbody, 3)): R (len(bodies), 3, 3) = R_hand^T R_body, t = R_hand^T (x_body - x_hand)."""
    rot = np.empty((len(bodies), 3, 3))
    pos = np.empty((len(bodies), 3))
    h = xmat[hand]
    for n in range(len(bodies)):
        body = bodies[n]
        for i in range(3):
            for j in range(3):
                rot[n, i, j] = h[i] * xmat[body, j] + h[3 + i] * xmat[body, 3 + j] + h[6 + i] * xmat[body, 6 + j]
            pos[n, i] = (h[i] * (xpos[body, 0] - xpos[hand, 0]) + h[3 + i] * (xpos[body, 1] - xpos[hand, 1])
                         + h[6 + i] * (xpos[body, 2] - xpos[hand, 2]))
    return rot, pos


@njit(cache=True)
def synthesize_clouds(bank, bank_part, index, refill, noise, noise_std, rot_a, pos_a, rot_b, pos_b, d_rot, d_pos):
    """Clouds (B, n, 3) float32 in hand_base from bank draws (``CloudSynthesizer._sample``).

    ``index`` (B, k): the distinct bank points of each cloud; ``refill`` (B, n - k): which of
    them repeat in the last n - k rows (the occlusion refill); ``noise`` (B, k, 3) standard
    normal draws scaled by ``noise_std`` (B,) (or (B, 0, 3): none); parts' poses R (B, 3, 3),
    t (B, 3) in hand_base. The episode's perturbation (d_rot, d_pos) moves leg a about its
    origin and leg b with it (it is an error of the tool pose): R_a' = R_a dR, t_a' = t_a + dt,
    and leg b keeps its pose relative to leg a.
    """
    n_batch, k = index.shape[0], index.shape[1]
    n = k + refill.shape[1]
    noisy = noise.shape[1] > 0
    out = np.empty((n_batch, n, 3), np.float32)
    ra, rb = np.empty((3, 3)), np.empty((3, 3))
    pa, pb, rel_pos = np.empty(3), np.empty(3), np.empty(3)
    for b in range(n_batch):
        # leg b relative to leg a: rel = R_a^T R_b, rel_pos = R_a^T (t_b - t_a)
        for i in range(3):
            rel_pos[i] = 0.0
            for j in range(3):
                rel_pos[i] += rot_a[b, j, i] * (pos_b[b, j] - pos_a[b, j])
        for i in range(3):
            for j in range(3):
                ra[i, j] = rot_a[b, i, 0] * d_rot[0, j] + rot_a[b, i, 1] * d_rot[1, j] + rot_a[b, i, 2] * d_rot[2, j]
            pa[i] = pos_a[b, i] + d_pos[i]
        for i in range(3):
            for j in range(3):  # R_b' = R_a' R_a^T R_b
                acc = 0.0
                for m in range(3):
                    rel = rot_a[b, 0, m] * rot_b[b, 0, j] + rot_a[b, 1, m] * rot_b[b, 1, j] + \
                        rot_a[b, 2, m] * rot_b[b, 2, j]
                    acc += ra[i, m] * rel
                rb[i, j] = acc
            pb[i] = ra[i, 0] * rel_pos[0] + ra[i, 1] * rel_pos[1] + ra[i, 2] * rel_pos[2] + pa[i]
        std = noise_std[b]
        for i in range(k):
            p = index[b, i]
            rot, pos = (rb, pb) if bank_part[p] == 1 else (ra, pa)
            for c in range(3):
                value = rot[c, 0] * bank[p, 0] + rot[c, 1] * bank[p, 1] + rot[c, 2] * bank[p, 2] + pos[c]
                if noisy:
                    value += noise[b, i, c] * std
                out[b, i, c] = value
        for i in range(n - k):
            for c in range(3):
                out[b, k + i, c] = out[b, refill[b, i], c]
    return out


__all__ = ["ORTHONORMALITY_TOLERANCE", "euler_angles_xyz", "hand_frame_poses", "matrices_to_rotvecs",
           "mean_displacement", "pose_check", "rotvecs_to_matrices", "synthesize_clouds"]
