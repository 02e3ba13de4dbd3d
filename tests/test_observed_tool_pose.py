"""``hingelab.perception.observed_tool_pose``: the three forms of the tool pose the high level observes, and the
``scripted-perceived`` demonstrator that acts on the observation's tool pose."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import hingelab.envs  # noqa: F401  (registers the envs)
from hingelab.errors import ConfigError
from hingelab.perception.grip_point import grip_points_world
from hingelab.perception.observed_tool_pose import ObservedToolPose
from hingelab.perception.registration import euler_xyz
from hingelab.perception.synthetic_dataset import nominal_tool_pose
from hingelab.policies.loading import load_policy
from hingelab.sim import scripted
from hingelab.tasks import OBSERVED_TOOL_POSE, OBSERVED_TOOL_POSITION


def _true_and_tracked(steps: int = 8, seed: int = 3):
    """A tool moving in the hand near the nominal pose, and what a tracker with a constant calibration error (a
    rotation of 25 degrees and 15 mm) reports of it."""
    rng = np.random.default_rng(seed)
    rot_nom, pos_nom = nominal_tool_pose()
    error_rot = Rotation.from_rotvec(np.deg2rad(25) * np.array([0.6, -0.64, 0.48])).as_matrix()
    error_pos = np.array([0.015, -0.01, 0.012])
    true, tracked = [], []
    rot, pos = rot_nom @ Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix(), pos_nom + [0.001, -0.002, 0.0015]
    for _ in range(steps):
        true.append((rot, pos))
        tracked.append((error_rot @ rot, error_rot @ pos + error_pos))
        rot = rot @ Rotation.from_rotvec(rng.normal(0, 0.03, 3)).as_matrix()
        pos = pos + rng.normal(0, 0.002, 3)
    return true, tracked, (rot_nom, pos_nom)


def _euler(rot):
    return euler_xyz(np.asarray(rot).reshape(1, 3, 3))[0]


def test_relative_cancels_a_constant_calibration_error_and_observes_the_motion_from_the_nominal_pose():
    true, tracked, nominal = _true_and_tracked()
    pose = ObservedToolPose("relative", nominal, alpha=1.0)  # unsmoothed: each frame on its own
    first_true = true[0]
    for k, ((rot, pos), (t_rot, t_pos)) in enumerate(zip(true, tracked)):
        obs = pose.reset(t_rot, t_pos, _euler(t_rot)) if k == 0 else pose.update(t_rot, t_pos, _euler(t_rot))
        # what the observation stands for: the nominal pose moved by the true motion since the first frame
        expected_rot = nominal[0] @ first_true[0].T @ rot
        expected_pos = nominal[1] + nominal[0] @ first_true[0].T @ (pos - first_true[1])
        np.testing.assert_allclose(pose.rotation(obs), expected_rot, atol=1e-9)
        np.testing.assert_allclose(obs[:3], expected_pos, atol=1e-12)
        assert np.abs(obs[3:]).max() < 0.5  # angles away from the nominal: near zero, never near +-pi
    # the paper's form carries the error, and its angles sit where they flip sign
    observed = ObservedToolPose("observed", nominal, alpha=1.0)
    obs = observed.reset(tracked[0][0], tracked[0][1], _euler(tracked[0][0]))
    assert np.linalg.norm(obs[:3] - true[0][1]) > 0.01
    assert np.abs(_euler(nominal[0])).max() > 3.0


def test_observed_and_anchored_smooth_as_the_paper_does():
    _, tracked, nominal = _true_and_tracked()
    observed, anchored = ObservedToolPose("observed", nominal), ObservedToolPose("anchored", nominal)
    raw = [np.concatenate([p, _euler(r)]) for r, p in tracked]
    smoothed = raw[0]
    observed.reset(*tracked[0], raw[0][3:])
    anchored.reset(*tracked[0], raw[0][3:])
    for k in range(1, len(raw)):
        smoothed = 0.9 * raw[k] + 0.1 * smoothed
        np.testing.assert_allclose(observed.update(*tracked[k], raw[k][3:]), smoothed, atol=1e-12)
        got = anchored.update(*tracked[k], raw[k][3:])
        np.testing.assert_allclose(got[:3], nominal[1] + smoothed[:3] - raw[0][:3], atol=1e-12)
        np.testing.assert_allclose(got[3:], smoothed[3:], atol=1e-12)


def test_a_bad_form_is_a_one_line_error():
    with pytest.raises(ConfigError, match="'true' is unknown; choose one of observed, anchored, relative, nominal"):
        ObservedToolPose("true", nominal_tool_pose())
    with pytest.raises(ConfigError, match="tool_position 'true' is unknown"):
        gym.make("hingelab/ToolPick-v0", tool_position="true")


def _grip_errors_mm(tool_position: str, steps: int = 12) -> np.ndarray:
    """The grip point rebuilt from the env's observation (as ``scripted-perceived`` rebuilds it) minus the
    simulator's, per step, while the scripted demonstrator approaches."""
    env = gym.make("hingelab/ToolPick-v0", object="sphere", size=0.02, low_level="privileged",
                   tool_position=tool_position)
    policy = load_policy("scripted")
    try:
        errors = []
        for seed in (0, 1, 2):
            obs, _ = env.reset(seed=seed)
            policy.reset(env, seed)
            pick = env.unwrapped
            for _ in range(steps):
                fresh = pick.tool_pose.observation()
                d, hand = pick.sim.data, pick.sim.reader.hand_body
                grip, _, _ = grip_points_world(fresh[OBSERVED_TOOL_POSITION].reshape(1, 3),
                                               pick.tool_pose.rotation(fresh[OBSERVED_TOOL_POSE]).reshape(1, 3, 3),
                                               pick.sample.z_smoothed[0].reshape(1, 2), d.xmat[hand].reshape(1, 3, 3),
                                               d.xpos[hand].reshape(1, 3), pick.perception.calibration)
                errors.append(1000 * np.linalg.norm(grip[0] - scripted.grip_point(pick.sim)))
                obs = env.step(policy.act(env, obs))[0]
        return np.asarray(errors)
    finally:
        env.close()


def test_the_relative_form_places_the_tips_where_they_are_and_the_paper_s_form_does_not():
    relative, observed = _grip_errors_mm("relative"), _grip_errors_mm("observed")
    assert np.median(relative) < 6.0  # the in-hand start's mm and the tracker's noise
    assert np.median(observed) > 10.0  # the clouds' per-episode calibration error: centimetres at the tips


def test_scripted_perceived_acts_on_the_observation_s_tool_pose():
    env = gym.make("hingelab/ToolPick-v0", object="sphere", size=0.02, low_level="privileged", tool_position="relative")
    policy = load_policy("scripted-perceived")
    try:
        obs, _ = env.reset(seed=4)
        policy.reset(env, 4)
        policy.act(env, obs)
        pick = env.unwrapped
        rebuilt = policy.heuristic.grip_point()
        assert np.linalg.norm(rebuilt - scripted.grip_point(pick.sim)) > 1e-6  # not the simulator's own
        assert np.linalg.norm(rebuilt - scripted.grip_point(pick.sim)) < 0.01
    finally:
        env.close()


def test_nominal_observes_the_nominal_pose_at_every_step_whatever_is_tracked():
    _, tracked, nominal = _true_and_tracked()
    pose = ObservedToolPose("nominal", nominal)
    observations = [pose.reset(*tracked[0], _euler(tracked[0][0]))]
    observations += [pose.update(r, p, _euler(r)) for r, p in tracked[1:]]
    for obs in observations:
        np.testing.assert_allclose(obs, np.concatenate([nominal[1], np.zeros(3)]), atol=1e-12)
        np.testing.assert_allclose(pose.rotation(obs), nominal[0], atol=1e-12)
