"""FastSAC is SB3's SAC, faster: same update, same saves, HER, determinism. Tiny nets, < 30 s.
And ``hingelab bench sac``, which measures it against SB3's SAC: its figures and its table (~20 s)."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC, HerReplayBuffer
from stable_baselines3.common.logger import configure

from hingelab.bench.sac import ARMS, BASELINE, OURS, build_table, ratio_name, update_rate
from hingelab.learners.sac.fast_sac import FastSAC

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
    model = cls("MultiInputPolicy", TinyGoalEnv(), buffer_size=500, batch_size=64, learning_starts=0, seed=seed,
                **kwargs)
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


# --- hingelab bench sac ------------------------------------------------------------------------


def test_update_rate_is_the_updates_it_ran_over_the_time_they_took():
    """Exactly n updates, timed from just before the first to just after the last."""
    model = _filled(FastSAC)
    model.train(gradient_steps=2, batch_size=64)
    before = model._n_updates
    seen, times = [], iter([100.0, 102.5])

    def clock():
        seen.append(model._n_updates)  # how many updates had run when the clock was read
        return next(times)

    assert update_rate(model, 5, 64, clock=clock) == pytest.approx(5 / 2.5)
    assert seen == [before, before + 5] and model._n_updates == before + 5


def test_bench_table_figures_are_medians_of_the_blocks_and_ratios_of_the_medians():
    rates = {1: {BASELINE: [50.0, 60.0, 40.0], "SB3 SAC + configure_torch": [52.0, 48.0, 70.0],
                 OURS: [80.0, 64.0, 66.0]},
             2: {BASELINE: [90.0, 10.0, 100.0], "SB3 SAC + configure_torch": [100.0, 110.0, 120.0],
                 OURS: [120.0, 30.0, 110.0]}}
    config = {"stable_baselines3": "x", "torch": "y", "batch_size": 256, "buffer_size": 100, "rounds": 3,
              "updates_per_block": 10, "profile_updates": 10}
    profile = {arm: {"backward (3 losses)": 5.0, "total under cProfile": 9.0} for arm in ARMS}
    table = build_table(rates, profile, config)
    rows = {(r["threads"], r["config"]): r for r in table.rows}
    assert set(rows) == {(t, arm) for t in (1, 2) for arm in ARMS}
    assert rows[(1, BASELINE)]["updates/s"] == 50.0 and rows[(1, OURS)]["updates/s"] == 66.0
    assert (rows[(2, OURS)]["min"], rows[(2, OURS)]["max"]) == (30.0, 120.0)
    assert rows[(1, OURS)]["ms/update"] == pytest.approx(1e3 / 66.0)
    assert rows[(1, OURS)]["/ SB3 SAC"] == pytest.approx(66.0 / 50.0)
    assert rows[(2, OURS)]["/ SB3 SAC"] == pytest.approx(110.0 / 90.0)
    assert table.ratios[ratio_name(1)] == pytest.approx(66.0 / 50.0)
    assert table.ratios[ratio_name(2)] == pytest.approx(110.0 / 90.0)
    assert list(table.ratios)[0] == ratio_name(1)  # the headline first
    assert table.config["block_rates"]["2"][OURS] == [120.0, 30.0, 110.0]
    assert any("backward (3 losses): 5.00 / 5.00 / 5.00" in note for note in table.notes)
    flagged = [note for note in table.notes if note.startswith("UNRELIABLE")]  # 10 to 100 updates/s at 2 threads
    assert len(flagged) == 1 and "at 2 threads" in flagged[0] and f"{BASELINE} 10-100" in flagged[0]
    assert f"{OURS} 30-120" in flagged[0] and "SB3 SAC + configure_torch" not in flagged[0]


def _head():
    from hingelab.paths import REPO_ROOT

    return subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True, text=True,
                          check=True).stdout.strip()


@pytest.mark.slow
def test_bench_sac_quick_writes_a_table_whose_figures_agree(tmp_path):
    """Slow (about a minute: three spawned worker processes building 2 x 256 nets over a 100,000-row
    buffer). By default its figures are covered by ``test_update_rate_is_the_updates_it_ran_over_the_time_they_took``
    and ``test_bench_table_figures_are_medians_of_the_blocks_and_ratios_of_the_medians`` (the same
    ``update_rate`` and ``build_table``), and a benchmark's command end to end (table files, code version)
    by ``test_cli.py::test_bench_sim_writes_its_table``."""
    from hingelab import __version__, provenance

    head_before = _head()
    result = subprocess.run([sys.executable, "-m", "hingelab.cli.main", "bench", "sac", "--quick", "--out",
                             str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    table = json.loads((tmp_path / "sac.json").read_text())
    assert ratio_name(1) in (tmp_path / "sac.md").read_text() and ratio_name(1) in result.stdout

    rows = {(r["threads"], r["config"]): r for r in table["rows"]}
    assert {(1, arm) for arm in ARMS} <= set(rows)  # and the compiled and SBX arms (tests/test_compiled_update.py)
    rounds = table["config"]["rounds"]
    for arm in ARMS:
        blocks = table["config"]["block_rates"]["1"][arm]
        assert len(blocks) == rounds and all(rate > 0 for rate in blocks)
        row = rows[(1, arm)]
        assert row["updates/s"] == pytest.approx(statistics.median(blocks), rel=1e-12)
        assert row["min"] <= row["updates/s"] <= row["max"]
        assert row["ms/update"] == pytest.approx(1e3 / row["updates/s"])
        assert row["role"] == ARMS[arm][0]
    ours, baseline = rows[(1, OURS)]["updates/s"], rows[(1, BASELINE)]["updates/s"]
    assert table["ratios"][ratio_name(1)] == pytest.approx(ours / baseline, rel=1e-12)
    assert rows[(1, OURS)]["/ SB3 SAC"] == pytest.approx(ours / baseline, rel=1e-12)
    assert 0.2 < ours / baseline < 5  # a quick run is noisy; a factor of 5 is a measuring bug

    for arm, parts in table["config"]["profile_ms_per_update"].items():  # the profile found each part
        for part in ("replay sampling + to-tensor", "actor forward (obs + next_obs, with squashed Gaussian)",
                     "critic forward (target + critic loss + actor loss)", "backward (3 losses)",
                     "Adam step (3 optimizers)", "polyak update"):
            assert parts[part] > 0, (arm, part)

    recorded = table["code"]["git_commit"]  # the code version as the run started
    assert recorded.split("+")[0] in {head_before, _head()}
    provenance.git_commit.cache_clear()
    assert ("+dirty" in recorded) == provenance.is_dirty(provenance.git_commit())
    assert table["code"]["hingelab_version"] == __version__
    assert table["config"]["torch"] == th.__version__ and table["config"]["quick"] is True
