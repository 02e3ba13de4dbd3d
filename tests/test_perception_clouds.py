"""Cloud synthesis: the sampled surface, hinge kinematics, realism options, seeding."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hingelab.errors import ConfigError
from hingelab.perception.clouds import IDEAL, TWEEZER_XML, CloudRealism, CloudSynthesizer, ToolGeometry, pose_matrix


@pytest.fixture(scope="module")
def geometry():
    return ToolGeometry.default()


@pytest.fixture(scope="module")
def tweezer():
    model = mujoco.MjModel.from_xml_path(str(TWEEZER_XML))
    return model, mujoco.MjData(model)


def test_bank_lies_on_the_outer_surface_of_each_part(geometry, tweezer):
    model, _ = tweezer
    for label, body in enumerate((geometry.body_a, geometry.body_b)):
        points = geometry.bank_points[geometry.bank_part == label]
        on_surface = np.zeros(len(points), bool)
        inside_other = np.zeros(len(points), bool)
        for g in np.flatnonzero(model.geom_bodyid == body):
            rot, centre = pose_matrix(model.geom_pos[g], model.geom_quat[g])
            local = np.abs((points - centre) @ rot) - model.geom_size[g]
            within = np.all(local <= 1e-7, axis=1)
            on_surface |= within & (np.abs(local).min(axis=1) < 1e-7)
            inside_other |= np.all(local < -1e-6, axis=1)
        assert on_surface.all() and not inside_other.any()
    # both parts sampled in proportion to their areas
    share_a = (geometry.bank_part == 0).mean()
    assert share_a == pytest.approx(geometry.part_areas_m2[0] / sum(geometry.part_areas_m2), abs=1e-3)


def test_geometry_is_deterministic(geometry, tweezer):
    again = ToolGeometry(tweezer[0])
    np.testing.assert_array_equal(again.bank_points, geometry.bank_points)
    assert again.geometry_hash == geometry.geometry_hash


@pytest.mark.parametrize("theta", [0.0, 0.12, 0.3])
def test_hinge_kinematics_match_mujoco(geometry, tweezer, theta):
    model, data = tweezer
    data.joint("tool_hinge").qpos = theta
    mujoco.mj_kinematics(model, data)
    rot, pos = geometry.leg_b_pose(theta)
    np.testing.assert_allclose(rot, data.body("tool_leg_b").xmat.reshape(3, 3), atol=1e-12)
    np.testing.assert_allclose(pos, data.body("tool_leg_b").xpos, atol=1e-12)
    gap = np.linalg.norm(data.site("tool_tip_a").xpos - data.site("tool_tip_b").xpos)
    assert geometry.tip_gap_m(theta) == pytest.approx(gap, abs=1e-12)


def test_cloud_from_sim_matches_the_privileged_pose(geometry):
    from hingelab.sim.core import SimCore

    sim = SimCore("tool_shape")
    state = sim.reset(seed=0)
    for _ in range(3):
        state = sim.step(hand_action=np.zeros(9)).state
    from_sim = CloudSynthesizer(geometry, IDEAL, seed=5).from_sim(sim.model, sim.data)
    rot, _ = pose_matrix(state.tool_pos_hand, state.tool_quat_hand)
    from_pose = CloudSynthesizer(geometry, IDEAL, seed=5).from_tool_pose(rot, state.tool_pos_hand, state.hinge_angle)
    assert from_sim.shape == (256, 3) and from_sim.dtype == np.float32
    np.testing.assert_allclose(from_sim, from_pose, atol=1e-6)


def test_realism_noise_removal_and_episode_perturbation(geometry):
    ideal = CloudSynthesizer(geometry, IDEAL, seed=1).from_tool_pose(np.eye(3), np.zeros(3), 0.1)
    noisy = CloudSynthesizer(geometry, CloudRealism(0.003, 0.0, 0.0, 0.0), seed=1).from_tool_pose(
        np.eye(3), np.zeros(3), 0.1)
    assert np.std(noisy - ideal) == pytest.approx(0.003, rel=0.1)  # same seed: same points, plus noise
    occluded = CloudSynthesizer(geometry, CloudRealism(0.0, 0.2, 0.0, 0.0), seed=1).from_tool_pose(
        np.eye(3), np.zeros(3), 0.1)
    assert occluded.shape == (256, 3) and len(np.unique(occluded, axis=0)) == 256 - round(0.2 * 256)
    synth = CloudSynthesizer(geometry, CloudRealism(), seed=2)
    angles, offsets = [], []
    for episode in range(30):
        synth.new_episode()
        rot, offset = synth.perturbation
        angles.append(Rotation.from_matrix(rot).as_euler("xyz"))
        offsets.append(offset)
        first = synth.perturbation
        synth.from_tool_pose(np.eye(3), np.zeros(3), 0.1)
        assert synth.perturbation is first  # fixed within the episode
    assert np.abs(angles).max() <= np.deg2rad(30) + 1e-9 and np.abs(offsets).max() <= 0.02
    assert np.abs(angles).max() > np.deg2rad(15)  # and it does perturb


def test_seeded_and_batched(geometry):
    rot = Rotation.from_euler("xyz", [[0.1, 0.2, 0.3], [0.0, -0.4, 1.0]]).as_matrix()
    pos = np.array([[0.0, 0.01, 0.1], [0.02, 0.0, 0.05]])
    a = CloudSynthesizer(geometry, CloudRealism(), seed=7)
    b = CloudSynthesizer(geometry, CloudRealism(), seed=7)
    a.new_episode(), b.new_episode()
    batch_a = a.from_tool_pose(rot, pos, [0.0, 0.3])
    np.testing.assert_array_equal(batch_a, b.from_tool_pose(rot, pos, [0.0, 0.3]))
    assert batch_a.shape == (2, 256, 3)
    with pytest.raises(ConfigError, match="removal_fraction"):
        CloudRealism(removal_fraction=1.0)


def test_per_cloud_noise_levels(geometry):
    """A noise level per cloud (the encoder's mixed-noise data): each cloud's spread about the
    ideal one is its own level; the same seed gives the same clouds."""
    rot, pos = np.repeat(np.eye(3)[None], 3, 0), np.zeros((3, 3))
    ideal = CloudSynthesizer(geometry, IDEAL, seed=1).from_tool_pose(rot, pos, 0.1)
    levels = np.array([0.0, 0.002, 0.006])
    noisy = CloudSynthesizer(geometry, IDEAL, seed=1).from_tool_pose(rot, pos, 0.1, noise_std_m=levels)
    np.testing.assert_allclose(np.std(noisy - ideal, axis=(1, 2)), levels, rtol=0.1, atol=1e-7)
    with pytest.raises(ConfigError, match="noise levels"):
        CloudSynthesizer(geometry, IDEAL, seed=1).from_tool_pose(rot, pos, 0.1, noise_std_m=[0.0, -0.001, 0.0])


def test_cloud_dataset_noise_range(geometry):
    from hingelab.perception.synthetic_dataset import CloudDatasetConfig, sample_clouds

    assert CloudDatasetConfig(noise_std_m=0.002, noise_std_max_m=0.006).noise_range_m == (0.002, 0.006)
    assert CloudDatasetConfig().noise_range_m == (0.005, 0.005)
    with pytest.raises(ConfigError, match="noise_std_max_m"):
        CloudDatasetConfig(noise_std_m=0.005, noise_std_max_m=0.003)
    batch = sample_clouds(np.random.default_rng(0), 200, geometry, CloudRealism(0.0, 0.2, 0.0, 0.0),
                          np.deg2rad(30), 0.02, noise_range_m=(0.002, 0.006))
    assert batch["noise_std_m"].min() >= 0.002 and batch["noise_std_m"].max() <= 0.006
    assert np.ptp(batch["noise_std_m"]) > 0.003  # it does vary


@pytest.mark.parametrize("population, size, batch", [(4096, 205, 3), (4096, 4096, 1), (100, 1, 2), (7, 7, 2)])
def test_compiled_draws_are_numpys_own(population, size, batch):
    """The clouds' compiled draws (generator_draws) give numpy's Generator.choice and .integers
    values draw for draw and leave the generator where numpy's calls would: a seed keeps its clouds."""
    from hingelab.perception import generator_draws

    for seed in range(20):
        ours, numpys = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(3):
            expected = np.stack([numpys.choice(population, size, replace=False) for _ in range(batch)])
            np.testing.assert_array_equal(generator_draws.choice(ours, population, size, batch), expected)
            for high in (1, 2, size, 51, 2**31):
                np.testing.assert_array_equal(generator_draws.integers(ours, high, (batch, 13)),
                                              numpys.integers(0, high, (batch, 13)))
        assert ours.random() == numpys.random()
    with pytest.raises(ValueError, match="without replacement"):
        generator_draws.choice(np.random.default_rng(0), 5, 6)


def test_part_poses_of_different_batch_sizes_are_refused(geometry):
    synthesizer = CloudSynthesizer(geometry, IDEAL, seed=0)
    with pytest.raises(ConfigError, match="different batch sizes"):
        synthesizer.from_tool_pose(np.stack([np.eye(3)] * 2), np.zeros(3), 0.1)
