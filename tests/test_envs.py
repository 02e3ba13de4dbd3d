"""The two Gymnasium environments: API, spaces, rewards, determinism, and SB3 on them."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import hingelab  # noqa: F401  (registers the envs)
from hingelab.envs import TOOL_PICK_ID, TOOL_SHAPE_ID
from hingelab.errors import ConfigError


@pytest.fixture(scope="module")
def shape_env():
    env = gym.make(TOOL_SHAPE_ID)
    yield env
    env.close()


@pytest.fixture(scope="module")
def pick_env():
    env = gym.make(TOOL_PICK_ID)
    yield env
    env.close()


def test_check_env_passes_for_both(shape_env, pick_env):
    check_env(shape_env.unwrapped, skip_render_check=True)
    check_env(pick_env.unwrapped, skip_render_check=True)


def test_tool_shape_spaces_and_goal_env_contract(shape_env):
    obs, info = shape_env.reset(seed=0)
    assert obs["observation"].shape == (26,)
    np.testing.assert_array_equal(obs["achieved_goal"], obs["observation"][-2:])
    assert "is_success" in info
    obs, reward, terminated, truncated, info = shape_env.step(np.zeros(9))
    env = shape_env.unwrapped
    # vectorized compute_reward agrees with the step's reward
    batch = env.compute_reward(np.stack([obs["achieved_goal"]] * 3), np.stack([obs["desired_goal"]] * 3),
                               [info] * 3)
    np.testing.assert_allclose(batch, reward)
    assert set(info["reward_terms"]) == {"goal", "effort_tool", "effort_fingers"}


def test_effort_term_switches_off():
    env = gym.make(TOOL_SHAPE_ID, use_effort=False)
    env.reset(seed=0)
    _, reward, *_, info = env.step(np.ones(9))
    assert info["reward_terms"]["effort_tool"] == 0.0 and info["reward_terms"]["effort_fingers"] == 0.0
    assert reward == pytest.approx(info["reward_terms"]["goal"])
    env.close()


def test_reachable_goals_lie_on_the_calibration_curve():
    env = gym.make(TOOL_SHAPE_ID, goal_sampling="reachable")
    calibration = env.unwrapped.calibration
    for seed in range(5):
        obs, _ = env.reset(seed=seed)
        opening = calibration.project_opening(obs["desired_goal"])
        back = calibration.z_for_opening(opening)
        assert np.linalg.norm(back - obs["desired_goal"]) < 0.05 * max(1e-3, env.unwrapped.success_threshold) + 1e-3
    env.close()


@pytest.mark.parametrize("sampler, end, bounds", [
    ("reachable_open", "open", (0.6, 0.8)),  # half of them, plus the uniform half's 40%
    ("reachable_closed", "closed", (0.52, 0.72)),  # half of them, plus the uniform half's 25%
])
def test_weighted_goals_put_more_of_them_at_their_end(sampler, end, bounds):
    from hingelab.envs.tool_shape import CLOSED_SHARE, OPEN_SHARE

    env = gym.make(TOOL_SHAPE_ID, goal_sampling=sampler).unwrapped
    env.np_random = np.random.default_rng(0)
    low, high = env.reachable_range
    openings = np.array([env.calibration.project_opening(env._sample_goal()) for _ in range(400)])
    assert openings.min() >= low - 1e-3 and openings.max() <= high + 1e-3
    if end == "open":
        share = np.mean(openings > high - OPEN_SHARE * (high - low))
    else:
        share = np.mean(openings < low + CLOSED_SHARE * (high - low))
    assert bounds[0] < share < bounds[1]
    env.close()


def test_a_goal_band_keeps_the_goals_inside_it():
    """goal_openings=(low, high): an expert's training goals, clipped to the reachable range."""
    env = gym.make(TOOL_SHAPE_ID, goal_sampling="reachable", goal_openings=(-1.0, 0.10)).unwrapped
    env.np_random = np.random.default_rng(0)
    assert env.goal_openings == (env.reachable_range[0], 0.10)
    openings = np.array([env.calibration.project_opening(env._sample_goal()) for _ in range(200)])
    assert openings.min() >= env.reachable_range[0] - 1e-3 and openings.max() <= 0.10 + 1e-3
    assert openings.max() > 0.08 and openings.min() < 0.02  # the whole band, not a corner of it
    env.close()
    for band, sampling, match in (((0.2, 0.1), "reachable", "not a band"), ((0.5, 0.9), "reachable", "not a band"),
                                  ((0.0, 0.1), "normal", "needs goal_sampling='reachable'")):
        with pytest.raises(ConfigError, match=match):
            gym.make(TOOL_SHAPE_ID, goal_sampling=sampling, goal_openings=band)


def test_same_seed_same_episode():
    def run():
        env = gym.make(TOOL_SHAPE_ID)
        obs, _ = env.reset(seed=7)
        rng = np.random.default_rng(0)
        rewards = [env.step(rng.uniform(-1, 1, 9))[1] for _ in range(5)]
        env.close()
        return obs["desired_goal"], rewards

    goal_a, rewards_a = run()
    goal_b, rewards_b = run()
    np.testing.assert_array_equal(goal_a, goal_b)
    np.testing.assert_array_equal(rewards_a, rewards_b)


def test_tool_pick_observation_is_in_the_hand_frame(pick_env):
    obs, info = pick_env.reset(seed=1)
    env = pick_env.unwrapped
    assert obs.shape == (14,)
    # target 5 cm above the object: in the hand frame they differ by 5 cm too
    assert np.linalg.norm(obs[11:14] - obs[8:11]) == pytest.approx(0.05, abs=0.01)
    np.testing.assert_allclose(env.target - env.object_start, [0, 0, 0.05])
    assert info["attempt"] == 1 and info["is_success"] == 0.0


def test_tool_pick_privileged_low_level_opens_to_the_goal(pick_env):
    env = pick_env.unwrapped
    pick_env.reset(seed=2)
    z_open = env.calibration_z(0.22) if hasattr(env, "calibration_z") else env.low_level.calibration.z_for_opening(0.22)
    action = np.concatenate([np.asarray(z_open) / 3.0, np.zeros(3)])
    for _ in range(15):
        *_, info = pick_env.step(action)
    assert info["hinge_angle"] == pytest.approx(0.22, abs=0.04)


def test_bad_arguments_are_one_line_errors():
    with pytest.raises(ConfigError, match="unknown object 'banana'"):
        gym.make(TOOL_PICK_ID, object="banana")
    with pytest.raises(ConfigError, match="out of range"):
        gym.make(TOOL_PICK_ID, size=0.3)
    with pytest.raises(ConfigError, match="does not exist"):
        gym.make(TOOL_PICK_ID, low_level="/nonexistent/low.zip")
    with pytest.raises(ConfigError, match="goal_sampling"):
        gym.make(TOOL_SHAPE_ID, goal_sampling="uniform")


def test_nan_action_is_refused(shape_env):
    shape_env.reset(seed=0)
    with pytest.raises(ConfigError, match="finite"):
        shape_env.step(np.full(9, np.nan))


def test_sb3_sac_and_her_run_on_the_envs(tmp_path):
    from stable_baselines3 import SAC, HerReplayBuffer

    shape = gym.make(TOOL_SHAPE_ID)
    model = SAC("MultiInputPolicy", shape, replay_buffer_class=HerReplayBuffer,
                replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future"),
                learning_starts=100, batch_size=32, policy_kwargs=dict(net_arch=[16]), seed=0, verbose=0)
    model.learn(total_timesteps=2000)
    assert model.num_timesteps == 2000 and model.replay_buffer.size() > 0
    pick = gym.make(TOOL_PICK_ID)
    model = SAC("MlpPolicy", pick, learning_starts=100, batch_size=32, policy_kwargs=dict(net_arch=[16]),
                seed=0, verbose=0)
    model.learn(total_timesteps=2000)
    assert model.num_timesteps == 2000


def test_diverging_episode_is_truncated_with_its_reason(pick_env):
    pick_env.reset(seed=3)
    pick_env.unwrapped.sim.data.qvel[:] = 1e12
    _, _, terminated, truncated, info = pick_env.step(np.zeros(5))
    assert truncated and not terminated and info["failure_reason"] == "divergence"


def test_tool_pick_ends_when_the_tool_leaves_the_hand():
    """Random high-level actions shake the tweezer out of the hand (real contacts, nothing moved by
    hand): the step where it is 3 cm from its start terminates with "tool_drop"; with
    terminate_on_drop=False the same step reports it and the episode runs on."""
    def until_drop(env):
        env.reset(seed=0)
        env.action_space.seed(0)
        for step in range(200):
            _, _, terminated, truncated, info = env.step(env.action_space.sample() * 0.3)
            if info["tool_dropped"] or terminated or truncated:
                return step, terminated, truncated, info
        return None

    ends = until_drop(gym.make(TOOL_PICK_ID))
    assert ends is not None, "the random actions did not drop the tool; pick another seed"
    step, terminated, truncated, info = ends
    assert terminated and not truncated and info["failure_reason"] == "tool_drop"
    assert info["tool_dropped"] and info["tool_drift_m"] > 0.03
    runs_on = gym.make(TOOL_PICK_ID, terminate_on_drop=False)
    again = until_drop(runs_on)
    assert again[0] == step and again[3]["tool_dropped"] and not again[1]
    *_, terminated, truncated, info = runs_on.step(np.zeros(5))
    assert not terminated and info["tool_dropped"]


def test_tool_pick_with_the_shipped_low_level_policy_follows_the_goal():
    """A scripted high level (arm still) asks the shipped low-level policy for a nearly closed and
    an open tweezer in turn; the tool's latent goes to each goal and the hinge follows (loose
    bounds: 3 success thresholds in latent distance, and the order of the openings).

    The open goal is 0.18 rad, at the low end of the open third of the reachable range
    (0.17-0.26 rad): of 100 fresh goals the shipped policy settled 28 of 34 open ones, all six
    misses beyond 0.22 rad (three overshot to the hinge limit); toward 0.22 rad it stopped at
    0.14 in this episode. That weakness is what the evaluation reports, not what this test checks."""
    from hingelab.envs.low_level import SHIPPED_LOW_LEVEL
    from hingelab.envs.tool_shape import latent_distance_for_gap

    assert SHIPPED_LOW_LEVEL.exists(), "the shipped low-level policy is missing: see assets/checkpoints/README.md"
    env = gym.make(TOOL_PICK_ID, low_level="policy")
    unwrapped = env.unwrapped
    assert unwrapped.low_level.kind == "policy"
    calibration = unwrapped.perception.calibration
    threshold = latent_distance_for_gap(calibration, 2.0)
    env.reset(seed=4)
    hinge, distance = {}, {}
    for opening in (0.03, 0.18):
        z_goal = np.asarray(calibration.z_for_opening(opening))
        action = np.concatenate([z_goal / 3.0, np.zeros(3)])
        z_seen = []
        for _ in range(40):
            *_, info = env.step(action)
            z_seen.append(unwrapped.sample.z_smoothed[0].copy())
        np.testing.assert_allclose(info["z_goal"], z_goal, atol=1e-6)
        hinge[opening] = info["hinge_angle"]
        distance[opening] = float(np.linalg.norm(np.mean(z_seen[-10:], axis=0) - z_goal))
    env.close()
    assert max(distance.values()) < 3 * threshold, (distance, threshold)
    assert hinge[0.18] - hinge[0.03] > 0.08, hinge


def test_bench_envs_replays_the_same_steps_as_its_raw_baseline(shape_env):
    """The bench's baseline is bare mj_step on the 1-worker run's own steps: replaying them from
    their recorded start states and controls reproduces the env's physics exactly."""
    import mujoco

    from hingelab.bench.envs import PHYSICS, _OneWorker

    worker = _OneWorker(TOOL_SHAPE_ID)
    assert worker.rate(15) > 0
    states, controls = worker.replay
    assert len(states) == len(controls) >= 10
    model, sim = worker.sim.model, worker.sim
    # the last replayed step ends where the env's last step ended
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, states[-1], PHYSICS)
    data.ctrl[:] = controls[-1]
    for _ in range(sim.n_substeps):
        mujoco.mj_step(model, data)
    end = np.empty(mujoco.mj_stateSize(model, PHYSICS))
    mujoco.mj_getState(model, sim.data, end, PHYSICS)
    replayed = np.empty_like(end)
    mujoco.mj_getState(model, data, replayed, PHYSICS)
    np.testing.assert_allclose(replayed, end, atol=1e-12)  # 15 steps of a 50-step episode: no reset came
    assert worker.replayed_raw_rate() > 0
    worker.env.close()


def test_a_low_level_checkpoint_folder_means_its_model_zip(tmp_path):
    import shutil

    from hingelab.envs.low_level import SHIPPED_LOW_LEVEL_SAC, PolicyLowLevel

    step = tmp_path / "checkpoints" / "step_000000010000"
    step.mkdir(parents=True)
    with pytest.raises(ConfigError, match="without a model.zip"):
        PolicyLowLevel(step)
    shutil.copy(SHIPPED_LOW_LEVEL_SAC, step / "model.zip")
    assert PolicyLowLevel(step).model.action_space.shape == (9,)
