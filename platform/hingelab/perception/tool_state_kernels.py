"""``ToolState.update``'s step between two resets, compiled (numba): one call per env step.

Between resets every tool is tracked from its predicted pose. In numpy that step is ~40
small array operations (the prediction, tracking's argument checks, Euler angles, the
differencing, the move into the tool frame, the encoder's input scaling); right after the
physics step each of them costs a few microseconds, a noticeable share of the step in all.
Here they are one pass over the same formulas, calling the tracking loop itself
(``registration_kernels.track_one``) and the pose kernels. The 3x3 rotation products and the
cloud's move into the tool frame are plain sums here where numpy uses BLAS, so results can
differ from the numpy path in the last bit (1e-16 relative); the tracking, the hinge and the
encoder's input are otherwise the same arithmetic. Anything unusual (a bad prior, a lost tool,
a turn near 180 degrees, gimbal lock) is flagged for ``ToolState`` to redo in its general path.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hingelab.perception.pose_kernels import (
    ORTHONORMALITY_TOLERANCE,
    euler_angles_xyz,
    matrices_to_rotvecs,
    pose_check,
    rotvecs_to_matrices,
)
from hingelab.perception.registration_kernels import track_one


@njit(cache=True)
def tracked_step(points, n_distinct, rot_prev, pos_prev, motion, share, hinge, dt, lost_rmse_m, input_offset,
                 input_scale, model_a, normals_a, grid_a, origin_a, core_a, offset_a, model_b, normals_b, grid_b,
                 origin_b, core_b, offset_b, resolution, core_margin, hinge_cross, hinge_perp, anchor, skew, b_rot,
                 b_pos, g_anchor, theta_lo, theta_hi, articulated, trim_fraction, k_r, k_t, max_iterations,
                 tolerance_rad, tolerance_m):
    """Track B tools from their previous poses and difference them (``ToolState`` steps 1-3).

    points (B, N, 3) hand_base m; rot_prev (B, 3, 3), pos_prev (B, 3): the last poses; motion
    (B, 6): the last step's v, omega, of which ``share`` (predict_motion * dt) moves the
    prediction; hinge (B,): the last openings. The rest: ``CanonicalRegistration.tracking_arguments``
    and ``registration.tracking_settings``.

    Returns rot (B, 3, 3), pos (B, 3), opening (B,), rmse (B,) m, Euler xyz (B, 3), v (B, 3) m/s,
    omega (B, 3) rad/s, the encoder's input ((B, n_distinct, 3) float32: the first n_distinct
    points in the tool frame, as float32, minus ``input_offset``, over ``input_scale``) and
    ``redo`` (B,) bool: tools for the general path (prior not a finite rotation, residual over
    ``lost_rmse_m``, a turn within ~0.6 degrees of 180, gimbal lock).
    """
    n_batch = points.shape[0]
    rot, pos = np.empty((n_batch, 3, 3)), np.empty((n_batch, 3))
    theta, rmse = np.empty(n_batch), np.empty(n_batch)
    redo = np.zeros(n_batch, np.bool_)
    turn = rotvecs_to_matrices(share * motion[:, 3:])
    rot_p, pos_p = np.empty((3, 3)), np.empty(3)
    for b in range(n_batch):
        for i in range(3):  # the predicted pose: the last one moved by part of the last motion
            for j in range(3):
                rot_p[i, j] = turn[b, i, 0] * rot_prev[b, 0, j] + turn[b, i, 1] * rot_prev[b, 1, j] + \
                    turn[b, i, 2] * rot_prev[b, 2, j]
            pos_p[i] = pos_prev[b, i] + share * motion[b, i]
        finite, orthonormality = pose_check(rot_p.reshape((1, 3, 3)), pos_p.reshape((1, 3)))
        if not finite or orthonormality > ORTHONORMALITY_TOLERANCE:  # registration._check_prior's test
            redo[b] = True
            continue
        start = min(max(hinge[b], theta_lo), theta_hi)
        rot[b], pos[b], theta[b], score = track_one(
            points[b], rot_p, pos_p, start, model_a, normals_a, grid_a, origin_a, core_a, offset_a, model_b,
            normals_b, grid_b, origin_b, core_b, offset_b, resolution, core_margin, hinge_cross, hinge_perp, anchor,
            skew, b_rot, b_pos, g_anchor, theta_lo, theta_hi, articulated, trim_fraction, k_r, k_t, max_iterations,
            tolerance_rad, tolerance_m)
        rmse[b] = np.sqrt(score)
        redo[b] = not rmse[b] <= lost_rmse_m
    for b in range(n_batch):  # poses of redone tools are not used; keep the arithmetic below finite
        if redo[b]:
            rot[b] = rot_prev[b]
            pos[b] = pos_prev[b]
            theta[b], rmse[b] = hinge[b], 0.0
    euler, locked = euler_angles_xyz(rot)
    relative = np.empty((n_batch, 3, 3))  # R_k R_{k-1}^T
    for b in range(n_batch):
        for i in range(3):
            for j in range(3):
                relative[b, i, j] = rot[b, i, 0] * rot_prev[b, j, 0] + rot[b, i, 1] * rot_prev[b, j, 1] + \
                    rot[b, i, 2] * rot_prev[b, j, 2]
    omega, near_pi = matrices_to_rotvecs(relative)
    velocity = np.empty((n_batch, 3))
    scaled = np.empty((n_batch, n_distinct, 3), np.float32)
    for b in range(n_batch):
        redo[b] = redo[b] or locked[b] or near_pi[b]
        for k in range(3):
            velocity[b, k] = (pos[b, k] - pos_prev[b, k]) / dt
            omega[b, k] = omega[b, k] / dt
        for i in range(n_distinct):  # q = R^T (p - t), as float32, then (q - offset) / scale in float32
            d0, d1, d2 = points[b, i, 0] - pos[b, 0], points[b, i, 1] - pos[b, 1], points[b, i, 2] - pos[b, 2]
            for k in range(3):
                local = np.float32(d0 * rot[b, 0, k] + d1 * rot[b, 1, k] + d2 * rot[b, 2, k])
                scaled[b, i, k] = (local - input_offset[k]) / input_scale
    return rot, pos, theta, rmse, euler, velocity, omega, scaled, redo
