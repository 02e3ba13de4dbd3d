"""FastSAC is SB3's SAC, faster: same update, same saves, HER, determinism. Tiny nets, < 30 s."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC, HerReplayBuffer
from stable_baselines3.common.logger import configure

from hingelab.learning.sac_speed import FastSAC, update_rate

NET = dict(net_arch=[32, 32])


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Tiny nets: a second OpenMP thread only spins, and crawls when the other core is busy."""
    threads = th.get_num_threads()
    th.set_num_threads(1)
    yield
    th.set_num_threads(threads)


class TinyGoalEnv(gym.Env):
    """A 2-D point pushed toward a goal; 10-step episodes ended by time limit (Fetch habit)."""

    def __init__(self):
        box = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = spaces.Dict(
            {"observation": spaces.Box(-1.0, 1.0, (4,), np.float32), "achieved_goal": box, "desired_goal": box}
        )
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.t = 0

    def _obs(self):
        obs = np.concatenate([self.pos, self.goal]).astype(np.float32)
        return {"observation": obs, "achieved_goal": self.pos.copy(), "desired_goal": self.goal.copy()}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(-0.5, 0.5, 2).astype(np.float32)
        self.goal = self.np_random.uniform(-0.5, 0.5, 2).astype(np.float32)
        self.t = 0
        return self._obs(), {"is_success": False}

    def compute_reward(self, achieved_goal, desired_goal, info):
        return -(np.linalg.norm(achieved_goal - desired_goal, axis=-1) > 0.1).astype(np.float32)

    def step(self, action):
        self.pos = np.clip(self.pos + 0.2 * action, -1.0, 1.0).astype(np.float32)
        self.t += 1
        success = bool(np.linalg.norm(self.pos - self.goal) <= 0.1)
        reward = float(self.compute_reward(self.pos, self.goal, None))
        return self._obs(), reward, False, self.t >= 10, {"is_success": success}


def _filled(cls, seed=0, **kwargs):
    """A model whose buffer holds 500 transitions with reward = -|a|^2 + obs[0] (learnable)."""
    kwargs.setdefault("policy_kwargs", dict(NET))
    model = cls("MultiInputPolicy", TinyGoalEnv(), buffer_size=500, batch_size=64, learning_starts=0, seed=seed, **kwargs)
    rb = model.replay_buffer
    rng = np.random.default_rng(123)
    for key in rb.observations:
        rb.observations[key][:] = rng.uniform(-1, 1, rb.observations[key].shape)
        rb.next_observations[key][:] = rng.uniform(-1, 1, rb.next_observations[key].shape)
    rb.actions[:] = rng.uniform(-1, 1, rb.actions.shape)
    rb.rewards[:] = -np.sum(rb.actions**2, axis=-1) + rb.observations["observation"][..., 0]
    rb.dones[:] = rng.random(rb.dones.shape) < 0.1
    rb.full = True
    model.set_logger(configure(None, []))
    return model


def _params(model):
    named = dict(model.policy.named_parameters())
    named.update({f"target.{k}": v for k, v in model.critic_target.named_parameters()})
    named["log_ent_coef"] = model.log_ent_coef
    return {k: v.detach().clone() for k, v in named.items()}


def _same_start(fast, sac):
    fast.policy.load_state_dict(sac.policy.state_dict())
    with th.no_grad():
        fast.log_ent_coef.copy_(sac.log_ent_coef)


def _train_both(fast, sac, steps):
    for model in (fast, sac):
        np.random.seed(7)  # the replay buffer samples with np.random
        th.manual_seed(7)  # the actor's Gaussian noise
        model.train(gradient_steps=steps, batch_size=64)


def test_same_update_as_sac_bitwise_with_the_same_adam():
    """Same weights, same batches, same noise: identical parameters after 3 updates."""
    fused = dict(NET, optimizer_kwargs=dict(fused=True))
    fast, sac = _filled(FastSAC), _filled(SAC, policy_kwargs=fused)
    sac.ent_coef_optimizer = th.optim.Adam([sac.log_ent_coef], lr=sac.lr_schedule(1), fused=True)
    _same_start(fast, sac)
    before = _params(sac)
    _train_both(fast, sac, 3)
    after_fast, after_sac = _params(fast), _params(sac)
    assert any(not th.equal(before[k], after_sac[k]) for k in before)
    for name in after_sac:
        th.testing.assert_close(after_fast[name], after_sac[name], rtol=0, atol=0, msg=name)
    for key in ("train/critic_loss", "train/actor_loss", "train/ent_coef", "train/ent_coef_loss"):
        assert fast.logger.name_to_value[key] == pytest.approx(sac.logger.name_to_value[key], rel=1e-6)


def test_same_update_as_plain_sac_within_adam_rounding():
    """Against SB3's default (for-loop) Adam: fused Adam rounds differently, |diff| < 1e-6."""
    fast, sac = _filled(FastSAC), _filled(SAC)
    _same_start(fast, sac)
    _train_both(fast, sac, 3)
    after_fast, after_sac = _params(fast), _params(sac)
    for name in after_sac:
        th.testing.assert_close(after_fast[name], after_sac[name], rtol=1e-5, atol=1e-6, msg=name)


def test_critic_loss_decreases_and_actor_moves():
    model = _filled(FastSAC, gamma=0.0, learning_rate=3e-3)  # gamma 0: the critic regresses the reward
    actor_before = [p.detach().clone() for p in model.actor.parameters()]
    model.train(gradient_steps=5, batch_size=64)
    first = model.logger.name_to_value["train/critic_loss"]
    model.train(gradient_steps=300, batch_size=64)
    model.train(gradient_steps=20, batch_size=64)
    last = model.logger.name_to_value["train/critic_loss"]
    assert last < 0.3 * first
    assert all(not th.equal(a, b) for a, b in zip(actor_before, model.actor.parameters()))
    assert update_rate(model, 5, 64) > 0


def test_save_load_roundtrip_also_as_plain_sac(tmp_path):
    model = _filled(FastSAC)
    model.train(gradient_steps=5, batch_size=64)
    model.save(tmp_path / "fast.zip")
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    obs = model.replay_buffer.sample(8).observations
    obs = {k: v.numpy() for k, v in obs.items()}
    expected = model.predict(obs, deterministic=True)[0]

    for cls in (FastSAC, SAC):
        loaded = cls.load(tmp_path / "fast.zip", env=TinyGoalEnv())
        for name, value in _params(model).items():
            th.testing.assert_close(_params(loaded)[name], value, rtol=0, atol=0, msg=name)
        np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], expected)
        loaded.load_replay_buffer(tmp_path / "buffer.pkl")
        loaded.set_logger(configure(None, []))
        loaded.train(gradient_steps=2, batch_size=64)
    assert isinstance(FastSAC.load(tmp_path / "fast.zip").actor.optimizer, th.optim.Adam)


def _her_run(seed):
    model = FastSAC(
        "MultiInputPolicy",
        TinyGoalEnv(),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future"),
        learning_starts=30,
        batch_size=32,
        policy_kwargs=dict(net_arch=[16, 16]),
        seed=seed,
    )
    return model.learn(total_timesteps=120)


def test_her_learn_and_same_seed_same_result():
    first, second = _her_run(3), _her_run(3)
    assert first._n_updates > 0
    for (name, a), b in zip(_params(first).items(), _params(second).values()):
        assert th.equal(a, b), name
