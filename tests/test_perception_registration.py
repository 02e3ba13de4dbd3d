"""Registration: accuracy on noisy occluded clouds, the opening estimate, batching, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hingelab.errors import ConfigError
from hingelab.perception.clouds import IDEAL, CloudRealism, CloudSynthesizer, ToolGeometry, random_rotations
from hingelab.perception.registration import CanonicalRegistration, kabsch, rotation_error_rad
from hingelab.perception.synthetic_dataset import nominal_tool_pose


@pytest.fixture(scope="module")
def registration():
    return CanonicalRegistration(ToolGeometry.default())


@pytest.fixture(scope="module")
def in_hand_clouds():
    """40 clouds around the in-hand pose (+-30 deg, +-2 cm), 3 mm noise, 20% removal, openings 0..0.3."""
    rng = np.random.default_rng(11)
    rot0, pos0 = nominal_tool_pose()
    rot = rot0 @ random_rotations(rng, 40, np.deg2rad(30))
    pos = pos0 + rng.uniform(-0.02, 0.02, (40, 3))
    theta = np.linspace(0.0, 0.3, 40)
    synth = CloudSynthesizer(ToolGeometry.default(), CloudRealism(max_offset_m=0, max_angle_rad=0), seed=3)
    return synth.from_tool_pose(rot, pos, theta), rot, pos, theta


def test_kabsch_recovers_a_known_motion():
    rng = np.random.default_rng(0)
    model = rng.normal(size=(1, 40, 3))
    rot = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    observed = model @ rot.T + [0.1, -0.2, 0.3]
    r, t = kabsch(model, observed, np.ones((1, 40)))
    np.testing.assert_allclose(r[0], rot, atol=1e-12)
    np.testing.assert_allclose(t[0], [0.1, -0.2, 0.3], atol=1e-12)


def test_exact_cloud_at_any_opening_registers_on_leg_a(registration):
    rot = Rotation.from_euler("xyz", [0.2, -0.3, 2.5]).as_matrix()
    errors, offsets = [], []
    for seed in range(4):  # four draws of the cloud's points: the error depends on which are drawn
        for theta in (0.0, 0.15, 0.3):
            cloud = CloudSynthesizer(registration.geometry, IDEAL, seed=seed).from_tool_pose(rot, [0.03, 0.04, 0.1],
                                                                                             theta)
            result = registration.register(cloud, prior=(rot, np.array([0.03, 0.04, 0.1])), hinge_prior=theta + 0.03)
            errors.append(np.rad2deg(rotation_error_rad(result.rotation, rot)))
            offsets.append(np.linalg.norm(result.translation - [0.03, 0.04, 0.1]))
            # closed, leg b's points crowd leg a's hinge block and pads: a known bias along the legs
            assert offsets[-1] < (0.004 if theta == 0 else 0.0025)
            assert result.hinge_angle == pytest.approx(theta, abs=0.02)
    # the canonical cloud is a 1024-point sample: ~1 degree and ~1 mm of discretization error, more on
    # an unlucky draw (over 20 draws: median 0.4 degrees and 0.3 mm, the worst 2.7 degrees and 2.7 mm)
    assert max(errors) < 3.0 and np.median(errors) < 1.0 and np.median(offsets) < 0.001


def test_noisy_occluded_clouds_from_the_in_hand_prior(registration, in_hand_clouds):
    clouds, rot, pos, theta = in_hand_clouds
    result = registration.register(clouds, prior=nominal_tool_pose())
    rot_err = np.rad2deg(rotation_error_rad(result.rotation, rot))
    pos_err = np.linalg.norm(result.translation - pos, axis=1)
    assert np.median(rot_err) < 7.0 and np.median(pos_err) < 0.004
    assert np.abs(result.hinge_angle - theta).mean() < 0.04
    np.testing.assert_allclose(Rotation.from_euler("xyz", result.euler_xyz).as_matrix(), result.rotation, atol=1e-9)


def test_batched_equals_one_by_one(registration, in_hand_clouds):
    clouds = in_hand_clouds[0][:3]
    batch = registration.register(clouds, prior=nominal_tool_pose())
    for k in range(3):
        single = registration.register(clouds[k], prior=nominal_tool_pose())
        np.testing.assert_allclose(single.rotation, batch.rotation[k], atol=1e-9)
        np.testing.assert_allclose(single.translation, batch.translation[k], atol=1e-12)


def test_global_start_without_a_prior(registration, in_hand_clouds):
    clouds, rot, _, _ = in_hand_clouds
    result = registration.register(clouds[:20])
    assert np.median(np.rad2deg(rotation_error_rad(result.rotation, rot[:20]))) < 8.0


@pytest.mark.parametrize("cloud, message", [
    (np.zeros((10, 3)), "at least 32"),
    (np.full((256, 3), np.nan), "NaN"),
    (np.zeros((256, 2)), "shape"),
    (np.zeros((2, 3, 256, 3)), "shape"),
])
def test_bad_clouds_are_refused_in_one_line(registration, cloud, message):
    with pytest.raises(ConfigError, match=message) as info:
        registration.register(cloud)
    assert "\n" not in str(info.value)


def test_bad_prior_is_refused(registration, in_hand_clouds):
    with pytest.raises(ConfigError, match="not a rotation"):
        registration.register(in_hand_clouds[0][0], prior=(np.eye(3) * 2, np.zeros(3)))


def test_compiled_tracking_matches_the_numpy_reference(registration, in_hand_clouds):
    """track (the compiled loop) and its numpy reference give the same poses, openings and
    residuals on one tool, and a batch gives what each tool gives alone (each stops on its own)."""
    from hingelab.perception.registration import TrackingConfig

    clouds, rot, pos, theta = in_hand_clouds
    rng = np.random.default_rng(3)
    rot_p = Rotation.from_rotvec(rng.normal(0, 0.03, (len(rot), 3))).as_matrix() @ rot
    pos_p = pos + rng.normal(0, 0.002, pos.shape)
    hinge = theta + rng.normal(0, 0.02, len(theta))
    for config in (TrackingConfig(), TrackingConfig(max_iterations=6, rotation_prior_m=0.0)):
        for i in range(len(clouds)):
            args = (clouds[i:i + 1], rot_p[i:i + 1], pos_p[i:i + 1], hinge[i:i + 1], config)
            fast, reference = registration.track(*args), registration.numpy_reference().track(*args)
            for name in ("rotation", "translation", "euler_xyz", "hinge_angle", "rmse_m"):
                np.testing.assert_allclose(getattr(fast, name), getattr(reference, name), atol=1e-9, err_msg=name)
        batch = registration.track(clouds, rot_p, pos_p, hinge, config)
        alone = [registration.track(clouds[i:i + 1], rot_p[i:i + 1], pos_p[i:i + 1], hinge[i:i + 1], config)
                 for i in range(len(clouds))]
        np.testing.assert_allclose(batch.rotation, np.concatenate([a.rotation for a in alone]), atol=1e-12)
        np.testing.assert_allclose(batch.hinge_angle, np.concatenate([a.hinge_angle for a in alone]), atol=1e-12)
    trimmed = registration.with_search(trim_fraction=0.1)
    args = (clouds[:2], rot_p[:2], pos_p[:2], hinge[:2])
    np.testing.assert_allclose(trimmed.track(*args).translation, trimmed.numpy_reference().track(*args).translation,
                               atol=1e-9)


def test_closed_form_rotation_conversions_match_scipy():
    from hingelab.perception.registration import euler_xyz, matrix_to_rotvec, rotvec_to_matrix

    rng = np.random.default_rng(0)
    for scale in (1e-9, 1e-5, 0.05, 1.0, 3.1):  # frame-to-frame turns up to nearly half a turn
        axis = rng.normal(size=(500, 3))
        vec = axis / np.linalg.norm(axis, axis=1, keepdims=True) * rng.uniform(0, scale, (500, 1))
        mat = Rotation.from_rotvec(vec).as_matrix()
        np.testing.assert_allclose(matrix_to_rotvec(mat), vec, atol=1e-10)
        np.testing.assert_allclose(rotvec_to_matrix(vec), mat, atol=1e-12)
    mat = Rotation.random(2000, random_state=1).as_matrix()
    np.testing.assert_allclose(euler_xyz(mat), Rotation.from_matrix(mat).as_euler("xyz"), atol=1e-10)
    np.testing.assert_allclose(matrix_to_rotvec(mat), Rotation.from_matrix(mat).as_rotvec(), atol=1e-9)
    locked = Rotation.from_euler("xyz", [[0.3, np.pi / 2, -0.2], [0.1, -np.pi / 2, 0.4]]).as_matrix()
    with pytest.warns(UserWarning, match="Gimbal lock"):  # scipy's, for the angles it cannot tell apart
        np.testing.assert_allclose(euler_xyz(locked), Rotation.from_matrix(locked).as_euler("xyz"), atol=1e-12)


def test_compiled_registration_matches_the_numpy_reference(registration, in_hand_clouds):
    """register's compiled iterations (voxel-map and exact nearest neighbours) give the numpy
    path's poses, openings and residuals, from the in-hand prior and from the global hypotheses."""
    clouds, rot, *_ = in_hand_clouds
    reference = registration.numpy_reference()
    for prior in (nominal_tool_pose(), None):
        fast, slow = registration.register(clouds[:12], prior=prior), reference.register(clouds[:12], prior=prior)
        for name in ("rotation", "translation", "hinge_angle", "rmse_m"):
            np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), atol=1e-9, err_msg=name)
    rigid = registration.with_search(trim_fraction=0.1)
    np.testing.assert_allclose(rigid.register(clouds[:4]).translation,
                               rigid.numpy_reference().register(clouds[:4]).translation, atol=1e-9)


def test_exact_nearest_neighbours_match_a_kd_tree(registration):
    """The compiled exact search (cell lists seeded by the voxel map) finds the k-d tree's nearest
    model point, near the legs and far from them."""
    from scipy.spatial import cKDTree

    from hingelab.perception import registration_kernels
    from hingelab.perception.registration import EXACT_CELL_M

    model = registration.leg_a
    cells = registration_kernels.cell_lists(model, EXACT_CELL_M, registration.config.grid_margin_m)
    rng = np.random.default_rng(0)
    queries = np.concatenate([model[rng.integers(0, len(model), 300)] + rng.normal(0, 0.004, (300, 3)),
                              rng.uniform(model.min(0) - 0.05, model.max(0) + 0.05, (300, 3))])
    dist, index = cKDTree(model).query(queries)
    grid = registration._grid_a
    for q, d, i in zip(queries, dist, index):
        d_grid, i_grid = grid.query(q[None])
        d_exact, i_exact = registration_kernels._exact_nearest(q, model, *cells, EXACT_CELL_M, float(d_grid[0]),
                                                          int(i_grid[0]))
        assert i_exact == i and abs(d_exact - d) < 1e-12


def test_compiled_pose_kernels_match_their_numpy_formulas():
    """The per-step kernels (cloud synthesis, the effort term's mean displacement, the prior's
    check) give the numpy formulas they replaced."""
    from hingelab.perception import pose_kernels

    rng = np.random.default_rng(3)
    rot = Rotation.random(4, random_state=2).as_matrix()
    pos = rng.normal(size=(4, 3))
    # clouds: leg a's pose turned by the episode's perturbation, leg b moved with it, noise, refill
    bank, part = rng.normal(size=(40, 3)), (rng.random(40) < 0.5).astype(np.int8)
    index, refill = np.stack([rng.permutation(40)[:30] for _ in range(2)]), rng.integers(0, 30, (2, 6))
    noise, std = rng.normal(size=(2, 30, 3)), np.array([0.0, 0.01])
    d_rot, d_pos = Rotation.random(random_state=4).as_matrix(), rng.normal(size=3)
    rot_a, pos_a = rot[:2] @ d_rot, pos[:2] + d_pos
    rot_b = rot_a @ np.swapaxes(rot[:2], 1, 2) @ rot[2:]
    pos_b = np.einsum("bij,bj->bi", rot_a, np.einsum("bji,bj->bi", rot[:2], pos[2:] - pos[:2])) + pos_a
    local = bank[index]
    on_b = part[index][..., None] == 1
    placed = np.where(on_b, np.einsum("bij,bnj->bni", rot_b, local) + pos_b[:, None],
                      np.einsum("bij,bnj->bni", rot_a, local) + pos_a[:, None]) + noise * std[:, None, None]
    expected = np.concatenate([placed, placed[np.arange(2)[:, None], refill]], axis=1).astype(np.float32)
    clouds = pose_kernels.synthesize_clouds(bank, part, index, refill, noise, std, rot[:2], pos[:2], rot[2:],
                                            pos[2:], d_rot, d_pos)
    assert clouds.dtype == np.float32 and clouds.shape == (2, 36, 3)
    np.testing.assert_allclose(clouds, expected, rtol=0, atol=1e-6)  # float32 rounding of ~1 m values
    no_noise = pose_kernels.synthesize_clouds(bank, part, index, refill, np.empty((2, 0, 3)), std, rot[:2],
                                              pos[:2], rot[2:], pos[2:], d_rot, d_pos)
    np.testing.assert_allclose(no_noise[0], clouds[0], rtol=0, atol=1e-6)
    points, shift = rng.normal(size=(256, 3)), rng.normal(size=3) * 0.01
    moved = points @ rot[0].T + shift
    assert pose_kernels.mean_displacement(points, rot[0], shift) == pytest.approx(
        np.linalg.norm(moved - points, axis=1).mean(), rel=1e-12)
    finite, error = pose_kernels.pose_check(rot, pos)
    assert finite and error < 1e-12
    skewed = rot.copy()
    skewed[1, 0, 0] += 0.01
    bad_pos = pos.copy()
    bad_pos[3, 1] = np.nan
    assert pose_kernels.pose_check(skewed, pos)[1] > 0.005 and not pose_kernels.pose_check(rot, bad_pos)[0]
