"""The registration's iterations, compiled (numba): the tracking loop and the fresh ICP loop.

In numpy these loops spend their time in per-call overhead, not arithmetic: each iteration is
~100 small array operations on 256 points (grid lookups, the articulated pairing, the 6x6
point-to-plane normal equations or the 3x3 SVD, the hinge's 2-D Procrustes), at a few microseconds
each, so numpy's tracking costs more per env step than the step's 25 physics steps (measured in
``analysis/bench/history/README.md``). These kernels do the same arithmetic in plain loops: the
same pairs, weights, steps and priors (the numpy versions stay,
``CanonicalRegistration.numpy_reference()``, and tests hold the two to 1e-9).
``track_one``/``track_batch``: ``CanonicalRegistration.track``; ``icp_iterations``: the coarse,
fine and exact stages of ``register`` (without reverse pairs).

One difference on batches: the numpy loop stops when no tool in the batch moved more than the
tolerances; here each tool stops on its own (the same on one tool, which is what an env tracks).

Compiled on first use and cached on disk next to this file (numba ``cache=True``): the first
call in a new checkout compiles them (tens of seconds), later processes load the cache.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hingelab.perception.pose_kernels import euler_angles_xyz, rotvecs_to_matrices


@njit(cache=True, inline="always")  # a call with array arguments costs reference counting
def _grid_lookup(q, origin, resolution, index, points):
    """Nearest model point by the voxel map: (distance, model index) of one query point."""
    c0 = min(max(np.int64(np.floor((q[0] - origin[0]) / resolution)), 0), index.shape[0] - 1)
    c1 = min(max(np.int64(np.floor((q[1] - origin[1]) / resolution)), 0), index.shape[1] - 1)
    c2 = min(max(np.int64(np.floor((q[2] - origin[2]) / resolution)), 0), index.shape[2] - 1)
    i = index[c0, c1, c2]
    d0, d1, d2 = q[0] - points[i, 0], q[1] - points[i, 1], q[2] - points[i, 2]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2), i


@njit(cache=True, inline="always")
def _core_index(q, origin, resolution, core, offset):
    """The model index the voxel map gives q, looked up in the map's core block
    (``registration._GridNearest.core``: the same voxels), or -1 for a point outside the block,
    which is then farther than the core's margin from every model point."""
    c0 = np.int64(np.floor((q[0] - origin[0]) / resolution)) - offset[0]
    c1 = np.int64(np.floor((q[1] - origin[1]) / resolution)) - offset[1]
    c2 = np.int64(np.floor((q[2] - origin[2]) / resolution)) - offset[2]
    if 0 <= c0 < core.shape[0] and 0 <= c1 < core.shape[1] and 0 <= c2 < core.shape[2]:
        return np.int64(core[c0, c1, c2])
    return np.int64(-1)


@njit(cache=True, inline="always")
def _distance_to(q, points, i):
    d0, d1, d2 = q[0] - points[i, 0], q[1] - points[i, 1], q[2] - points[i, 2]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(cache=True)
def _leg_b_pose(theta, skew, b_rot, b_pos, g_anchor):
    """Leg b's pose in the tool frame at hinge angle theta (``CanonicalRegistration._leg_b_fast``)."""
    hinge_rot = np.eye(3) + np.sin(theta) * skew + (1 - np.cos(theta)) * (skew @ skew)
    rot = b_rot @ hinge_rot
    return rot, b_rot @ g_anchor + b_pos - rot @ g_anchor


@njit(cache=True, inline="always")  # in the per-point loops: inlined, as if written there
def _to_tool_frames(points, i, rot, pos, rot_b, pos_b, local, local_b):
    """Cloud point i (hand_base) into the tool frame (local = R^T (p - t)) and leg b's frame."""
    for k in range(3):
        local[k] = (rot[0, k] * (points[i, 0] - pos[0]) + rot[1, k] * (points[i, 1] - pos[1])
                    + rot[2, k] * (points[i, 2] - pos[2]))
    for k in range(3):
        local_b[k] = (rot_b[0, k] * (local[0] - pos_b[0]) + rot_b[1, k] * (local[1] - pos_b[1])
                      + rot_b[2, k] * (local[2] - pos_b[2]))


@njit(cache=True, inline="always")
def _trim_weights(dist, trim_fraction, w):
    """w = 1 for the pairs kept, 0 for the worst ``trim_fraction`` (registration._trim_weights)."""
    if trim_fraction > 0:
        cutoff = np.sort(dist)[int(np.floor((1 - trim_fraction) * dist.shape[0])) - 1]
        for i in range(dist.shape[0]):
            w[i] = 1.0 if dist[i] <= cutoff else 0.0
    else:
        w[:] = 1.0


@njit(cache=True, inline="always")
def _hinge_update(points, rot, pos, theta, on_b, w, index_b, hinge_cross, hinge_perp, anchor, theta_lo, theta_hi):
    """The hinge's 2-D Procrustes on leg b's pairs in the (new) tool frame: the opening that turns
    the matched leg-b model points onto the cloud (registration._update_hinge / _track_hinge);
    theta unchanged with fewer than 3 leg-b pairs."""
    cross, dot, count = 0.0, 0.0, 0
    q = np.empty(3)
    for i in range(points.shape[0]):
        if on_b[i] and w[i] > 0:
            count += 1
            for k in range(3):  # R^T (p - t) - anchor
                q[k] = (rot[0, k] * (points[i, 0] - pos[0]) + rot[1, k] * (points[i, 1] - pos[1])
                        + rot[2, k] * (points[i, 2] - pos[2]) - anchor[k])
            ib = index_b[i]
            cross += w[i] * (q[0] * hinge_cross[ib, 0] + q[1] * hinge_cross[ib, 1] + q[2] * hinge_cross[ib, 2])
            dot += w[i] * (q[0] * hinge_perp[ib, 0] + q[1] * hinge_perp[ib, 1] + q[2] * hinge_perp[ib, 2])
    if count >= 3:
        return min(max(np.arctan2(cross, dot), theta_lo), theta_hi)
    return theta


@njit(cache=True)
def track_one(points, rot_p, pos_p, theta, model_a, normals_a, grid_a, origin_a, core_a, offset_a, model_b,
              normals_b, grid_b, origin_b, core_b, offset_b, resolution, core_margin, hinge_cross, hinge_perp, anchor,
              skew, b_rot, b_pos, g_anchor, theta_lo, theta_hi, articulated, trim_fraction, k_r, k_t, max_iterations,
              tolerance_rad, tolerance_m):
    """Track one cloud (N, 3) from the predicted pose (rot_p, pos_p) and opening theta.

    ``core_margin``: a distance (m) that no point outside a leg's core block comes nearer its
    leg than (the blocks' margin, a little less for rounding at their edges).

    Returns (rotation (3, 3), translation (3,), hinge angle, score): score is the weighted mean
    squared point-to-point distance of the last iteration's pairs (before its update).
    """
    n = points.shape[0]
    rot, pos = rot_p.copy(), pos_p.copy()
    model = np.empty((n, 3))  # paired model points and normals, tool frame
    normal = np.empty((n, 3))
    dist = np.empty(n)
    on_b = np.empty(n, np.bool_)
    index_b = np.empty(n, np.int64)
    w = np.empty(n)
    local = np.empty(3)
    local_b = np.empty(3)
    score = 0.0
    for _ in range(max_iterations):
        rot_b, pos_b = _leg_b_pose(theta, skew, b_rot, b_pos, g_anchor)
        for i in range(n):
            _to_tool_frames(points, i, rot, pos, rot_b, pos_b, local, local_b)
            ia = _core_index(local, origin_a, resolution, core_a, offset_a)
            ib = _core_index(local_b, origin_b, resolution, core_b, offset_b)
            da = _distance_to(local, model_a, ia) if ia >= 0 else np.inf
            db = _distance_to(local_b, model_b, ib) if ib >= 0 else np.inf
            # a point outside a leg's core is farther than core_margin from that leg: when the
            # other leg is nearer than that, the pair is the other leg's whatever the whole map
            # says, so the map (out of the cache after the physics) is read only otherwise
            if ia < 0 and not db < core_margin:
                da, ia = _grid_lookup(local, origin_a, resolution, grid_a, model_a)
            if ib < 0 and not da < core_margin:
                db, ib = _grid_lookup(local_b, origin_b, resolution, grid_b, model_b)
            index_b[i] = ib
            if db < da:
                on_b[i] = True
                dist[i] = db
                for k in range(3):
                    model[i, k] = (rot_b[k, 0] * model_b[ib, 0] + rot_b[k, 1] * model_b[ib, 1]
                                   + rot_b[k, 2] * model_b[ib, 2] + pos_b[k])
                    normal[i, k] = (rot_b[k, 0] * normals_b[ib, 0] + rot_b[k, 1] * normals_b[ib, 1]
                                    + rot_b[k, 2] * normals_b[ib, 2])
            else:
                on_b[i] = False
                dist[i] = da
                for k in range(3):
                    model[i, k] = model_a[ia, k]
                    normal[i, k] = normals_a[ia, k]
        _trim_weights(dist, trim_fraction, w)
        w /= w.sum()  # normalized to sum 1
        score = 0.0
        centre = np.zeros(3)
        for i in range(n):
            score += w[i] * dist[i] * dist[i]
            for k in range(3):
                centre[k] += w[i] * points[i, k]
        # one Gauss-Newton step of point-to-plane ICP with the motion prior (registration._plane_step),
        # pairs in hand_base: m = R m_tool + t, n = R n_tool
        hess = np.zeros((6, 6))
        grad = np.zeros(6)
        jac = np.empty(6)
        m = np.empty(3)
        nv = np.empty(3)
        arm = np.empty(3)
        for i in range(n):
            for k in range(3):
                m[k] = rot[k, 0] * model[i, 0] + rot[k, 1] * model[i, 1] + rot[k, 2] * model[i, 2] + pos[k]
                nv[k] = rot[k, 0] * normal[i, 0] + rot[k, 1] * normal[i, 1] + rot[k, 2] * normal[i, 2]
                arm[k] = m[k] - centre[k]
            jac[0] = arm[1] * nv[2] - arm[2] * nv[1]
            jac[1] = arm[2] * nv[0] - arm[0] * nv[2]
            jac[2] = arm[0] * nv[1] - arm[1] * nv[0]
            jac[3], jac[4], jac[5] = nv[0], nv[1], nv[2]
            residual = (points[i, 0] - m[0]) * nv[0] + (points[i, 1] - m[1]) * nv[1] + (points[i, 2] - m[2]) * nv[2]
            for a in range(6):
                grad[a] += w[i] * jac[a] * residual
                for b in range(a, 6):  # upper triangle; mirrored below
                    hess[a, b] += w[i] * jac[a] * jac[b]
        for a in range(6):
            for b in range(a):
                hess[a, b] = hess[b, a]
        rel = rot @ rot_p.T
        e_r = 0.5 * np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
        lever = np.zeros((3, 6))  # d(new origin) / d(omega, tau) = [-skew(t - c), I]
        off = pos - centre
        lever[0, 1], lever[0, 2], lever[1, 2] = off[2], -off[1], off[0]
        lever[1, 0], lever[2, 0], lever[2, 1] = -off[2], off[1], -off[0]
        for k in range(3):
            lever[k, 3 + k] = 1.0
        hess += k_t * (lever.T @ lever)
        for k in range(3):
            hess[k, k] += k_r
        for k in range(6):
            hess[k, k] += 1e-12
        grad -= k_t * (lever.T @ (pos - pos_p))
        grad[:3] -= k_r * e_r
        step = np.linalg.solve(hess, grad)
        turn = rotvecs_to_matrices(step[None, :3])[0]
        new_pos = centre + turn @ (pos - centre) + step[3:]
        rot = turn @ rot
        moved = np.abs(new_pos - pos).max()
        pos = new_pos
        if articulated:
            theta = _hinge_update(points, rot, pos, theta, on_b, w, index_b, hinge_cross, hinge_perp, anchor,
                                  theta_lo, theta_hi)
        if np.abs(step[:3]).max() < tolerance_rad and moved < tolerance_m:
            break
    return rot, pos, theta, score


@njit(cache=True)
def track_batch(points, rot_p, pos_p, theta, model_a, normals_a, grid_a, origin_a, core_a, offset_a, model_b,
                normals_b, grid_b, origin_b, core_b, offset_b, resolution, core_margin, hinge_cross, hinge_perp, anchor,
                skew, b_rot, b_pos, g_anchor, theta_lo, theta_hi, articulated, trim_fraction, k_r, k_t, max_iterations,
                tolerance_rad, tolerance_m):
    """``track_one`` over a batch: points (B, N, 3), rot_p (B, 3, 3), pos_p (B, 3), theta (B,).

    Returns rotations (B, 3, 3), translations (B, 3), hinge angles (B,), scores (B,) and the
    rotations' Euler angles (``pose_kernels.euler_angles_xyz``: angles (B, 3), locked (B,)).
    """
    n_batch = points.shape[0]
    rot, pos = np.empty((n_batch, 3, 3)), np.empty((n_batch, 3))
    hinge, score = np.empty(n_batch), np.empty(n_batch)
    for b in range(n_batch):
        rot[b], pos[b], hinge[b], score[b] = track_one(
            points[b], rot_p[b], pos_p[b], theta[b], model_a, normals_a, grid_a, origin_a, core_a, offset_a, model_b,
            normals_b, grid_b, origin_b, core_b, offset_b, resolution, core_margin, hinge_cross, hinge_perp, anchor,
            skew, b_rot, b_pos, g_anchor, theta_lo, theta_hi, articulated, trim_fraction, k_r, k_t, max_iterations,
            tolerance_rad, tolerance_m)
    euler, locked = euler_angles_xyz(rot)
    return rot, pos, hinge, score, euler, locked


# ---------------------------------------------------------------------- fresh registration
# ``CanonicalRegistration.register``'s iterations (point-to-point ICP, articulated), compiled the
# same way: its hypotheses are made in numpy, then every coarse, fine and exact iteration runs here.


@njit(cache=True)
def cell_lists(points, cell_m, margin_m):
    """Model points sorted into cubic cells of ``cell_m`` (CSR: start (n_cells + 1,), order) for
    exact nearest-neighbour search; returns (origin (3,), shape (3,), start, order)."""
    lo = np.empty(3)
    shape = np.empty(3, np.int64)
    for k in range(3):
        lo[k] = points[:, k].min() - margin_m
        shape[k] = np.int64(np.ceil((points[:, k].max() + margin_m - lo[k]) / cell_m)) + 1
    n = points.shape[0]
    cell = np.empty(n, np.int64)
    for i in range(n):
        c = 0
        for k in range(3):
            c = c * shape[k] + np.int64(np.floor((points[i, k] - lo[k]) / cell_m))
        cell[i] = c
    order = np.argsort(cell, kind="mergesort")
    start = np.zeros(shape[0] * shape[1] * shape[2] + 1, np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(1, start.shape[0]):
        start[c] += start[c - 1]
    return lo, shape, start, order


@njit(cache=True)
def _exact_nearest(q, points, lo, shape, start, order, cell_m, bound, bound_i):
    """Exact nearest model point to q, given a model point ``bound_i`` at distance ``bound``
    (the voxel map's answer, at most a voxel off): only the cells that meet the ball of that
    radius around q can hold a nearer point (cells outside the box hold none). Returns
    (distance, index); ``bound_i`` -1 with a finite bound asks only for points nearer than it."""
    best, best_i = bound * bound, bound_i
    c_lo = np.empty(3, np.int64)
    c_hi = np.empty(3, np.int64)
    for k in range(3):
        c_lo[k] = max(np.int64(np.floor((q[k] - bound - lo[k]) / cell_m)), 0)
        c_hi[k] = min(np.int64(np.floor((q[k] + bound - lo[k]) / cell_m)), shape[k] - 1)
    for x in range(c_lo[0], c_hi[0] + 1):
        for y in range(c_lo[1], c_hi[1] + 1):
            for z in range(c_lo[2], c_hi[2] + 1):
                cell = (x * shape[1] + y) * shape[2] + z
                for j in range(start[cell], start[cell + 1]):
                    i = order[j]
                    d = (q[0] - points[i, 0]) ** 2 + (q[1] - points[i, 1]) ** 2 + (q[2] - points[i, 2]) ** 2
                    if d < best:
                        best, best_i = d, i
    return np.sqrt(best), best_i


@njit(cache=True)
def _kabsch(model, observed, w):
    """Weighted best rigid motion observed ~ R model + t (registration.kabsch for one candidate)."""
    total = w.sum()
    mu_m, mu_o = np.zeros(3), np.zeros(3)
    for i in range(model.shape[0]):
        for k in range(3):
            mu_m[k] += w[i] * model[i, k]
            mu_o[k] += w[i] * observed[i, k]
    mu_m /= max(total, 1e-12)
    mu_o /= max(total, 1e-12)
    cov = np.zeros((3, 3))
    for i in range(model.shape[0]):
        for a in range(3):
            for b in range(3):
                cov[a, b] += w[i] / max(total, 1e-12) * (model[i, a] - mu_m[a]) * (observed[i, b] - mu_o[b])
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    fix = np.eye(3)
    fix[2, 2] = d
    rot = vt.T @ fix @ u.T
    return rot, mu_o - rot @ mu_m


@njit(cache=True)
def icp_iterations(points, rot0, pos0, theta0, iterations, exact, model_a, grid_a, origin_a, model_b, grid_b,
                   origin_b, resolution, cells_a, cells_b, cell_m, hinge_cross, hinge_perp, anchor, skew, b_rot,
                   b_pos, g_anchor, theta_lo, theta_hi, articulated, reference_opening, trim_fraction):
    """``iterations`` point-to-point ICP steps (``CanonicalRegistration._step`` without reverse
    pairs) for C candidates: points (C, N, 3), poses (C, 3, 3), (C, 3), openings (C,).
    Nearest neighbours from the voxel maps, or exact (``exact``: cell lists ``cells_a/b`` =
    (origin, shape, start, order)). Returns (rot, pos, theta, score (C,)): score as in _step."""
    n_cand, n = points.shape[0], points.shape[1]
    rot_out, pos_out = rot0.copy(), pos0.copy()
    theta_out, score_out = theta0.copy(), np.full(n_cand, np.nan)
    model = np.empty((n, 3))
    dist = np.empty(n)
    on_b = np.empty(n, np.bool_)
    index_b = np.empty(n, np.int64)
    w = np.empty(n)
    local = np.empty(3)
    local_b = np.empty(3)
    for c in range(n_cand):
        rot, pos, theta = rot0[c].copy(), pos0[c].copy(), theta0[c]
        p = points[c]
        for _ in range(iterations):
            rot_b, pos_b = _leg_b_pose(theta if articulated else reference_opening, skew, b_rot, b_pos, g_anchor)
            for i in range(n):
                _to_tool_frames(p, i, rot, pos, rot_b, pos_b, local, local_b)
                da, ia = _grid_lookup(local, origin_a, resolution, grid_a, model_a)
                db, ib = _grid_lookup(local_b, origin_b, resolution, grid_b, model_b)
                if exact:  # refine the voxel maps' answers; leg b only matters if nearer than leg a
                    da, ia = _exact_nearest(local, model_a, cells_a[0], cells_a[1], cells_a[2], cells_a[3], cell_m,
                                            da, ia)
                    if db < da:
                        db, ib = _exact_nearest(local_b, model_b, cells_b[0], cells_b[1], cells_b[2], cells_b[3],
                                                cell_m, db, ib)
                    else:  # only a leg-b point nearer than leg a's would change the pair
                        db_near, ib_near = _exact_nearest(local_b, model_b, cells_b[0], cells_b[1], cells_b[2],
                                                          cells_b[3], cell_m, da, -1)
                        if ib_near >= 0:
                            db, ib = db_near, ib_near
                index_b[i] = ib
                if db < da:
                    on_b[i] = True
                    dist[i] = db
                    for k in range(3):
                        model[i, k] = (rot_b[k, 0] * model_b[ib, 0] + rot_b[k, 1] * model_b[ib, 1]
                                       + rot_b[k, 2] * model_b[ib, 2] + pos_b[k])
                else:
                    on_b[i] = False
                    dist[i] = da
                    for k in range(3):
                        model[i, k] = model_a[ia, k]
            _trim_weights(dist, trim_fraction, w)
            score = 0.0
            for i in range(n):
                score += w[i] * dist[i] * dist[i]
            score /= w.sum()
            rot, pos = _kabsch(model, p, w)
            if articulated:  # in the new tool frame, as _update_hinge
                theta = _hinge_update(p, rot, pos, theta, on_b, w, index_b, hinge_cross, hinge_perp, anchor,
                                      theta_lo, theta_hi)
            score_out[c] = score
        rot_out[c], pos_out[c], theta_out[c] = rot, pos, theta
    return rot_out, pos_out, theta_out, score_out
