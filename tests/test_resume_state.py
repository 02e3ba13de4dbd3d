"""A run's resume state in plain formats: replay buffers (HER's info dicts too) and RNG states
round-trip exactly; a buffer of another shape, or a damaged file, is a one-line ConfigError."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch
from gymnasium import spaces

from hingelab.errors import ConfigError
from hingelab.training.resume_state import load_buffer, restore_rng_states, rng_states, save_buffer


def _her_buffer(env):
    from stable_baselines3 import HerReplayBuffer

    return HerReplayBuffer(200, env.observation_space, env.action_space, env=env, n_envs=2, copy_info_dict=True)


def test_a_her_buffer_with_its_info_dicts_round_trips(tmp_path):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from hingelab.rollouts.low_level import make_eval_env

    env = DummyVecEnv([lambda: make_eval_env({"max_episode_steps": 5})] * 2)
    try:
        buffer = _her_buffer(env)
        rng = np.random.default_rng(0)
        observations = env.reset()
        for _ in range(12):  # a few whole episodes per env slot, with the env's own info dicts
            actions = rng.uniform(-1, 1, size=(2, *env.action_space.shape)).astype(np.float32)
            next_observations, rewards, dones, infos = env.step(actions)
            buffer.add(observations, next_observations, actions, rewards, dones, infos)
            observations = next_observations
        save_buffer(buffer, tmp_path / "her.npz")
        copy = _her_buffer(env)
        load_buffer(copy, tmp_path / "her.npz")
        assert copy.pos == buffer.pos == 12 and copy.full == buffer.full
        for key in buffer.observations:
            np.testing.assert_array_equal(copy.observations[key], buffer.observations[key])
        np.testing.assert_array_equal(copy.ep_length, buffer.ep_length)
        np.testing.assert_array_equal(copy._current_ep_start, buffer._current_ep_start)
        assert copy.infos[3, 1].keys() == buffer.infos[3, 1].keys() and copy.infos[3, 1]  # filled, same keys
        for key, value in buffer.infos[3, 1].items():
            assert type(copy.infos[3, 1][key]) is type(value)  # a float32 term stays float32
        np.random.seed(5)
        ours = copy.sample(32, env=None)
        np.random.seed(5)
        theirs = buffer.sample(32, env=None)
        assert torch.equal(ours.rewards, theirs.rewards)  # relabelled rewards, from the restored infos
        assert torch.equal(ours.actions, theirs.actions)
    finally:
        env.close()


def test_rng_states_round_trip_through_json():
    from hingelab.training import resume_state as plain_state

    torch.manual_seed(3), np.random.seed(3), random.seed(3)
    states = plain_state.loads(plain_state.dumps(rng_states()))
    draws = (torch.rand(4), np.random.rand(4), random.random())
    restore_rng_states(states)
    again = (torch.rand(4), np.random.rand(4), random.random())
    assert torch.equal(draws[0], again[0]) and np.array_equal(draws[1], again[1]) and draws[2] == again[2]


def test_a_buffer_of_another_shape_or_a_damaged_file_is_refused(tmp_path):
    from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer

    box = spaces.Box(-1, 1, (3,))
    buffer = ReplayBuffer(10, box, box)
    buffer.add(np.zeros(3), np.ones(3), np.zeros(3), np.zeros(1), np.zeros(1), [{}])
    save_buffer(buffer, tmp_path / "b.npz")
    with pytest.raises(ConfigError, match="buffer_size=10, this run.s 20"):
        load_buffer(ReplayBuffer(20, box, box), tmp_path / "b.npz")
    with pytest.raises(ConfigError, match=r"observations is float32\[1, 1, 3\] \(rows written\), this run's is "
                                          r"float32\[10, 1, 4\]"):
        load_buffer(ReplayBuffer(10, spaces.Box(-1, 1, (4,)), box), tmp_path / "b.npz")
    with pytest.raises(ConfigError, match="holds a ReplayBuffer, this run uses a DictReplayBuffer"):
        load_buffer(DictReplayBuffer(10, spaces.Dict({"x": box}), box), tmp_path / "b.npz")
    raw = (tmp_path / "b.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ConfigError, match="cut.npz is not a readable replay buffer"):
        load_buffer(ReplayBuffer(10, box, box), tmp_path / "cut.npz")


def test_non_finite_numbers_round_trip_as_strict_json():
    """A NaN statistic in a checkpoint's state comes back bit for bit, and the text is JSON (no bare NaN)."""
    import json
    import math
    from collections import deque

    from hingelab.training.resume_state import dumps, loads

    doc = {"mean": float("nan"), "bounds": [1.0, float("inf")], "rewards": deque([float("-inf"), 2.0]),
           "array": np.array([np.nan, 1.5, -np.inf], dtype=np.float32), "scalar": np.float32("nan")}
    text = dumps(doc)
    json.loads(text, parse_constant=lambda name: pytest.fail(f"bare {name} in the state"))
    back = loads(text)
    assert math.isnan(back["mean"]) and back["bounds"] == [1.0, math.inf]
    assert back["rewards"][0] == -math.inf and back["rewards"][1] == 2.0
    assert back["array"].dtype == np.float32 and np.array_equal(back["array"], doc["array"], equal_nan=True)
    assert back["scalar"].dtype == np.float32 and np.isnan(back["scalar"])
