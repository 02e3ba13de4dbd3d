"""The privileged replay buffer: heuristic demos -> ToolPick-v0 transitions -> an SB3 SAC buffer."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

from hingelab.cli.main import main
from hingelab.envs import TOOL_PICK_ID, TOOL_SHAPE_ID
from hingelab.envs.rewards import HighLevelRewardConfig
from hingelab.episodes import create_dataset
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.transitions import dataset_transitions
from hingelab.errors import ConfigError
from hingelab.training.high_level_demos import fill_high_level_buffer, high_level_transitions


@pytest.fixture(scope="module")
def heuristic(tmp_path_factory):
    out = tmp_path_factory.mktemp("hlp") / "sphere"
    assert main(["generate", "heuristic", "--episodes", "3", "--object", "sphere", "--out", str(out),
                 "--no-progress"]) in (0, None)
    return out


@pytest.fixture(scope="module")
def recorded(heuristic):
    """The recorded transitions as they are, and each step's recorded reward terms and latent."""
    dataset = Dataset(heuristic)
    raw = dataset_transitions(dataset)
    terms, z_bar = [], []
    for episode in dataset.iter_episodes(topics=[S.TOPIC_STEP, S.TOPIC_REWARD, S.TOPIC_LATENT]):
        n = len(episode[S.TOPIC_STEP]["reward"])  # the reset's record (row 0) is no transition
        terms.append({k: v[1:n + 1] for k, v in episode[S.TOPIC_REWARD].items()})
        z_bar.append(episode[S.TOPIC_LATENT]["z_smoothed"][1:n + 1])
    terms = {k: np.concatenate([t[k] for t in terms]) for k in terms[0]}
    return raw, terms, np.concatenate(z_bar)


def test_default_relabelled_rewards_are_the_recorded_ones(heuristic, recorded):
    raw, terms, _ = recorded
    tr = high_level_transitions([heuristic])
    assert len(tr) == len(raw) > 100 and len(np.unique(tr.episode_index)) == 3
    assert tr.observations.shape == (len(tr), 14) and tr.actions.shape == (len(tr), 5)
    np.testing.assert_allclose(tr.rewards, raw.rewards, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tr.rewards, terms["total"], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(tr.observations, raw.observations)
    np.testing.assert_array_equal(tr.next_observations, raw.next_observations)
    np.testing.assert_array_equal(tr.terminated, raw.terminated)
    assert tr.rewards[tr.terminated].min() > 10  # every episode ends in success: the sparse bonus is in


def test_changed_weights_relabel_by_the_formula(heuristic, recorded):
    raw, terms, _ = recorded
    base = HighLevelRewardConfig()
    # c_h2: exp(-c d) = (exp(-c0 d)) ** (c / c0) exactly by the formula
    c2 = high_level_transitions([heuristic], dataclasses.replace(base, c_h2=35.0))
    np.testing.assert_allclose(c2.rewards - raw.rewards, terms["tool_object"] ** (35.0 / base.c_h2)
                               - terms["tool_object"], rtol=1e-9, atol=1e-12)
    assert np.abs(c2.rewards - raw.rewards).max() > 1e-3
    # c_h1 (success bonus) and c_h3 (object-target weight): linear in the weights
    changed = dataclasses.replace(base, c_h1=4.0, c_h3=2.5)
    c13 = high_level_transitions([heuristic], changed)
    success = raw.infos["is_success"] > 0.5
    # the absorbing term's R_max = 1 + c_h3 changes with c_h3 too
    expected = ((4.0 - base.c_h1 + changed.absorbing_bonus - base.absorbing_bonus) * success
                + (2.5 / base.c_h3 - 1) * terms["object_target"])
    np.testing.assert_allclose(c13.rewards - raw.rewards, expected, rtol=1e-9, atol=1e-12)
    # the penalty: far lowered to 5 cm, c_h5 2: -2 wherever a distance exceeds 5 cm
    near = high_level_transitions([heuristic], dataclasses.replace(base, far=0.05, c_h5=2.0))
    d_tool = -np.log(terms["tool_object"]) / base.c_h2
    far = (d_tool > 0.05) | (raw.infos["object_target_distance"] > 0.05) | (raw.infos["table_collision"] > 0.5)
    assert 0 < far.sum() < len(far)
    np.testing.assert_allclose(near.rewards - raw.rewards, -2.0 * far, rtol=0, atol=1e-9)


def test_actions_are_the_reached_latent_and_the_executed_velocity(heuristic, recorded):
    raw, _, z_bar = recorded
    tr = high_level_transitions([heuristic])
    np.testing.assert_array_equal(tr.actions[:, :2], np.clip(z_bar / 3.0, -1, 1))
    np.testing.assert_array_equal(tr.actions, raw.actions)  # the heuristic records the paper's action already
    np.testing.assert_array_equal(high_level_transitions([heuristic], actions="recorded").actions, raw.actions)
    assert np.abs(tr.actions).max() <= 1.0 and np.ptp(tr.actions[:, :2], axis=0).min() > 0.01


def test_sac_buffer_fills_and_samples_dataset_rows(heuristic):
    from stable_baselines3 import SAC

    tr = high_level_transitions([heuristic])
    env = gym.make(TOOL_PICK_ID)
    try:
        model = SAC("MlpPolicy", env, buffer_size=2000, learning_starts=0, device="cpu", seed=0)
    finally:
        env.close()
    buffer = model.replay_buffer
    assert fill_high_level_buffer(buffer, tr) == len(tr) and buffer.size() == len(tr) and buffer.pos == len(tr)
    def row(obs, action, next_obs, reward, done):
        return tuple(np.concatenate([obs, action, next_obs, [reward, done]]).astype(np.float32))

    # observations repeat under the observation delay: a row is all of a transition's fields
    rows = {row(tr.observations[i], tr.actions[i], tr.next_observations[i], tr.rewards[i],
                float(tr.terminated[i] or tr.truncated[i])) for i in range(len(tr))}
    batch = buffer.sample(128)
    sampled = {row(batch.observations[j].numpy(), batch.actions[j].numpy(), batch.next_observations[j].numpy(),
                   batch.rewards[j].item(), batch.dones[j].item()) for j in range(128)}
    assert sampled <= rows and len(sampled) > 64
    # the bulk path writes the same storage
    bulk = SAC("MlpPolicy", model.env, buffer_size=2000, device="cpu", seed=0).replay_buffer
    assert fill_high_level_buffer(bulk, tr, method="bulk") == len(tr) and bulk.size() == len(tr)
    for name in ("observations", "next_observations", "actions", "rewards", "dones"):
        np.testing.assert_array_equal(getattr(bulk, name)[:len(tr)], getattr(buffer, name)[:len(tr)])
    small = SAC("MlpPolicy", model.env, buffer_size=100, device="cpu").replay_buffer
    with pytest.raises(ConfigError, match="room for 100"):
        fill_high_level_buffer(small, tr)


def test_a_low_level_dataset_is_a_one_line_error_naming_it(tmp_path, heuristic):
    from hingelab.envs.recording import RecordingWrapper

    root = tmp_path / "low"
    create_dataset(root, name="low", source="low_level_training")
    env = RecordingWrapper(gym.make(TOOL_SHAPE_ID, max_episode_steps=2), root, source="low_level_training",
                           action_level="low")
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    (path,) = env.paths
    with pytest.raises(DatasetError) as err:
        high_level_transitions([heuristic, root])
    message = str(err.value)
    assert "\n" not in message and str(path) in message and TOOL_SHAPE_ID in message and "'low'" in message
    with pytest.raises(DatasetError, match="do not match the reward config") as err:
        high_level_transitions([heuristic], recorded_reward=HighLevelRewardConfig(c_h3=2.0))
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="success radius"):
        high_level_transitions([heuristic], HighLevelRewardConfig(success_radius=0.02))


def test_demo_share_buffer_keeps_the_demos_in_every_batch(heuristic, tmp_path):
    from stable_baselines3 import SAC

    from hingelab.training.high_level_demos import DemoShareReplayBuffer
    from hingelab.training.resume_state import load_buffer, save_buffer

    tr = high_level_transitions([heuristic])
    # a demo row: its observation (the buffer keeps the float64 observation space) and float32 action; a
    # reset observation alone may be a demo's too (the same episode seed)
    demo_rows = {(tuple(o), tuple(a)) for o, a in zip(tr.observations, tr.actions.astype(np.float32))}

    def in_demos(samples):
        return np.array([(tuple(o), tuple(a)) in demo_rows
                         for o, a in zip(samples.observations.numpy(), samples.actions.numpy())])
    env = gym.make(TOOL_PICK_ID)
    try:
        model = SAC("MlpPolicy", env, buffer_size=500, learning_starts=1000, device="cpu", seed=0,
                    replay_buffer_class=DemoShareReplayBuffer, replay_buffer_kwargs={"demos": tr, "demo_share": 0.25})
        buffer = model.replay_buffer
        assert buffer.demos.size() == len(tr) and buffer.size() == 0
        empty = buffer.sample(40)  # nothing of its own yet: all demos
        assert in_demos(empty).all()
        model.learn(total_timesteps=30)  # random actions, no training (learning_starts)
    finally:
        env.close()
    assert buffer.size() == 30 and buffer.demos.size() == len(tr)
    batch = buffer.sample(100)
    from_demos = in_demos(batch)
    assert from_demos[:25].all() and not from_demos[25:].any() and batch.rewards.shape == (100, 1)
    model.train(gradient_steps=2, batch_size=32)  # SAC's updates take the mixed batches
    assert model._n_updates == 2
    save_buffer(buffer, tmp_path / "buffer.npz")  # a checkpoint's, read back into the buffer a resume builds
    copy = DemoShareReplayBuffer(500, buffer.observation_space, buffer.action_space, demos=tr, demo_share=0.25)
    load_buffer(copy, tmp_path / "buffer.npz")
    assert copy.size() == 30 and copy.demos.size() == len(tr)
    np.testing.assert_array_equal(copy.observations, buffer.observations)
    np.testing.assert_array_equal(copy.demos.actions, buffer.demos.actions)
    with pytest.raises(ConfigError, match="demo_share"):
        DemoShareReplayBuffer(10, buffer.observation_space, buffer.action_space, demos=tr, demo_share=1.5)
