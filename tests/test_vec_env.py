"""PinnedVecEnv: SubprocVecEnv's contract through shared memory, checked against DummyVecEnv."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from hingelab.envs.vec_env import PinnedVecEnv


def _shape_env(max_steps: int = 6):
    import hingelab  # noqa: F401  (registers the envs in a spawned worker)

    return gym.make("hingelab/ToolShape-v0", goal_sampling="reachable", max_episode_steps=max_steps)


class _Broken(gym.Env):
    observation_space = gym.spaces.Box(-1, 1, (2,))
    action_space = gym.spaces.Box(-1, 1, (1,))

    def reset(self, *, seed=None, options=None):
        return np.zeros(2, np.float32), {}

    def step(self, action):
        raise ValueError("this env breaks on its first step")


def _broken():
    return _Broken()


def test_steps_resets_and_attributes_match_dummy_vec_env():
    fns = [functools.partial(_shape_env), functools.partial(_shape_env)]
    pinned, dummy = PinnedVecEnv(fns), DummyVecEnv(fns)
    try:
        for vec in (pinned, dummy):
            vec.seed(5)
        obs_p, obs_d = pinned.reset(), dummy.reset()
        for key in obs_d:
            np.testing.assert_array_equal(obs_p[key], obs_d[key])
        rng = np.random.default_rng(0)
        resets = 0
        for _ in range(8):  # through one auto-reset (episodes of 6 steps)
            actions = rng.uniform(-0.5, 0.5, (2, 9)).astype(np.float32)
            (op, rp, dp, ip), (od, rd, dd, idd) = pinned.step(actions), dummy.step(actions)
            for key in od:
                np.testing.assert_array_equal(op[key], od[key])
            np.testing.assert_allclose(rp, rd, rtol=1e-6)  # DummyVecEnv keeps rewards in float32, SubprocVecEnv not
            np.testing.assert_array_equal(dp, dd)
            resets += sum("terminal_observation" in i for i in ip)
            for a, b in zip(ip, idd):
                assert a["latent_distance"] == b["latent_distance"]
                assert a["TimeLimit.truncated"] == b["TimeLimit.truncated"]
                if "terminal_observation" in b:
                    np.testing.assert_array_equal(a["terminal_observation"]["observation"],
                                                  b["terminal_observation"]["observation"])
        assert resets == 2  # both envs reset once, as in DummyVecEnv
        assert pinned.get_attr("success_threshold") == dummy.get_attr("success_threshold")
        pinned.set_attr("marker", 3, indices=[1])
        assert pinned.get_attr("marker", indices=[1]) == [3]
        assert pinned.env_method("compute_reward", np.zeros((1, 2)), np.zeros((1, 2)), {}, indices=[0])[0].shape == (1,)
    finally:
        pinned.close()
        dummy.close()


def test_a_worker_error_names_the_env():
    vec = PinnedVecEnv([_broken, _broken], pin=False)
    try:
        vec.reset()
        with pytest.raises(RuntimeError, match="env worker 0 failed: ValueError: this env breaks"):
            vec.step(np.zeros((2, 1), np.float32))
    finally:
        vec.close()


class _BrokenMethod(_Broken):
    def step(self, action):
        return np.zeros(2, np.float32), 0.0, False, False, {}

    def explode(self):
        raise ValueError("explode")


def test_an_error_in_one_env_names_that_env():
    vec = PinnedVecEnv([_BrokenMethod, _BrokenMethod], pin=False)
    try:
        vec.reset()
        with pytest.raises(RuntimeError, match="env worker 1 failed: ValueError: explode"):
            vec.env_method("explode", indices=[1])
    finally:
        vec.close()
