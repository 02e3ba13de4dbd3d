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
    for theta in (0.0, 0.15, 0.3):
        cloud = CloudSynthesizer(registration.geometry, IDEAL, seed=1).from_tool_pose(rot, [0.03, 0.04, 0.1], theta)
        result = registration.register(cloud, prior=(rot, np.array([0.03, 0.04, 0.1])), hinge_prior=theta + 0.03)
        # the canonical cloud is a 1024-point sample: ~1 degree of discretization error
        assert np.rad2deg(rotation_error_rad(result.rotation, rot)) < 2.5
        # closed, leg b's points crowd leg a's hinge block and pads: a known ~3 mm bias along the legs
        assert np.linalg.norm(result.translation - [0.03, 0.04, 0.1]) < (0.004 if theta == 0 else 0.0015)
        assert result.hinge_angle == pytest.approx(theta, abs=0.02)


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
