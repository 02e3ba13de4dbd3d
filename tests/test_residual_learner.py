"""hingelab train high --learner residual-sac on tiny sizes: the policy at step 0 is its base, the critic
warm-up leaves the actor alone, exploration stays under its bound, the demos' residuals execute the
demonstrated actions, the ensemble is the members' own networks, exact resume, and bad input."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.learners import registry
from hingelab.learners.residual.config import ResidualSACConfig
from hingelab.learners.residual.networks import EnsembleCritic
from hingelab.learners.residual.run import ResidualRun, residual_transitions, train_residual
from hingelab.paths import ASSETS_DIR
from hingelab.policies import load_policy
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL
from hingelab.policies.phase_clone import PhaseClone
from hingelab.policies.residual import ResidualPolicy, compose, euler_xyz_to_6d
from hingelab.training import checkpoints as ckpt

TINY = ResidualSACConfig(
    steps=240, n_envs=1, max_episode_steps=40, learning_starts=40, actor_start=120, batch_size=16, buffer_size=2000,
    net_arch=(32, 32), critics=4, eval_every=120, eval_episodes=1, checkpoint_every=80, keep_checkpoints=10,
    prior_episodes=2, critic_pretrain_updates=10, low_level="privileged", randomize=False)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("residual") / "tiny"
    return run, train_residual(TINY, run, progress=False)


def _setup(tmp_path, **changes):
    """A run set up, not trained; without the prior's demos unless asked (generating them takes a while)."""
    changes = {"prior": False, **changes}
    return ResidualRun(replace(TINY, **changes), tmp_path / "run", progress=False).setup()


def _close(run):
    run.env.close()
    run.close_evaluator()


def test_euler_angles_become_the_rotation_matrix_first_two_columns():
    angles = np.random.default_rng(0).uniform(-np.pi, np.pi, (50, 3))
    matrices = Rotation.from_euler("xyz", angles).as_matrix()
    np.testing.assert_allclose(euler_xyz_to_6d(angles), np.concatenate([matrices[:, :, 0], matrices[:, :, 1]], 1),
                               atol=1e-12)
    # the same rotation written with angles 2 pi apart (a flip near +-pi) gives the same input
    np.testing.assert_allclose(euler_xyz_to_6d(angles), euler_xyz_to_6d(angles + 2 * np.pi), atol=1e-12)


def test_at_step_0_the_residual_policy_acts_exactly_as_its_base(tmp_path):
    run = _setup(tmp_path)
    try:
        policy, base = run.current_policy(), PhaseClone.load(SHIPPED_HIGH_LEVEL)
        obs = np.random.default_rng(1).normal(0, 0.05, (64, base.observation_dim)).astype(np.float32)
        state = None
        base_state = None
        for _ in range(3):  # the memory runs on alike
            ours, state = policy.predict(obs, state)
            theirs, base_state = base.predict(obs, base_state)
            np.testing.assert_array_equal(ours, theirs)
            np.testing.assert_array_equal(state, base_state)
        # the saved policy too, loaded as eval high loads it
        run.save_policy(tmp_path / "step0.zip")
        loaded = load_policy(tmp_path / "step0.zip", level="high")
        assert isinstance(loaded, ResidualPolicy)
        np.testing.assert_array_equal(loaded.predict(obs)[0], base.predict(obs)[0])
    finally:
        _close(run)


def test_critic_warm_up_leaves_the_actor_untouched_then_the_actor_moves(tmp_path):
    run = _setup(tmp_path, steps=0)
    model = run.model
    try:
        rng = np.random.default_rng(2)
        buffer = model.replay_buffer
        for _ in range(64):
            x = rng.normal(0, 1, (1, run.policy.inputs.dim)).astype(np.float32)
            buffer.add(x, x, rng.uniform(-1, 1, (1, 5)).astype(np.float32), np.array([1.0]), np.array([False]),
                       [{}])
        from stable_baselines3.common.logger import configure

        model.set_logger(configure(folder=None, format_strings=[]))
        actor = {k: v.clone() for k, v in model.actor.state_dict().items()}
        critic = {k: v.clone() for k, v in model.critic.state_dict().items()}
        alpha = model.log_ent_coef.detach().clone()
        model.num_timesteps = TINY.actor_start - 1
        model.train(gradient_steps=5, batch_size=16)
        assert all(torch.equal(v, model.actor.state_dict()[k]) for k, v in actor.items())
        assert torch.equal(alpha, model.log_ent_coef.detach())
        assert any(not torch.equal(v, model.critic.state_dict()[k]) for k, v in critic.items())
        model.num_timesteps = TINY.actor_start
        model.pretrain_critic(5, batch_size=16)  # --critic-pretrain: critic-only whatever the step
        assert all(torch.equal(v, model.actor.state_dict()[k]) for k, v in actor.items())
        model.train(gradient_steps=5, batch_size=16)
        assert any(not torch.equal(v, model.actor.state_dict()[k]) for k, v in actor.items())
    finally:
        _close(run)


def test_exploration_noise_stays_within_the_bound(tmp_path):
    bound = np.array([0.01, 0.02, 0.05, 0.08, 0.1])
    run = _setup(tmp_path, exploration_bound=tuple(bound), residual_scale=(0.1, 0.1, 0.3, 0.3, 0.3))
    try:
        model = run.model
        with torch.no_grad():  # a temperature that wants all the noise it can get: the cap still holds
            model.actor.log_std.bias.fill_(5.0)
        x = torch.as_tensor(np.random.default_rng(3).normal(0, 1, (1, run.policy.inputs.dim)), dtype=torch.float32)
        x = x.repeat(4000, 1)
        x[:, -5:] = 0.0  # the base's action: 0, away from the clip
        residual, _ = model.predict(x.numpy(), deterministic=False)
        executed = compose(np.zeros(5), residual, run.policy.scale)
        spread = executed.std(axis=0)
        assert (spread <= bound * 1.02).all() and (spread >= bound * 0.5).all(), spread
    finally:
        _close(run)


def test_an_exploration_floor_keeps_noise_on_every_dimension(tmp_path):
    bound, floor = np.array([0.01, 0.02, 0.05, 0.08, 0.1]), np.array([0.005, 0.01, 0.025, 0.04, 0.05])
    run = _setup(tmp_path, exploration_bound=tuple(bound), exploration_floor=tuple(floor),
                 residual_scale=(0.1, 0.1, 0.3, 0.3, 0.3))
    try:
        model = run.model
        with torch.no_grad():  # a temperature that wants no noise at all: the floor still holds
            model.actor.log_std.bias.fill_(-20.0)
        x = torch.as_tensor(np.random.default_rng(3).normal(0, 1, (1, run.policy.inputs.dim)), dtype=torch.float32)
        x = x.repeat(4000, 1)
        x[:, -5:] = 0.0
        residual, _ = model.predict(x.numpy(), deterministic=False)
        spread = compose(np.zeros(5), residual, run.policy.scale).std(axis=0)
        assert (spread >= floor * 0.9).all() and (spread <= floor * 1.1).all(), spread
        # the floor is no weight: a run with one saves and loads the same tensors as one without
        assert "log_std_min" not in model.actor.state_dict()
    finally:
        _close(run)
    with pytest.raises(ConfigError, match="exploration-floor"):
        replace(TINY, exploration_floor=(0.02, 0.01, 0.01, 0.01, 0.01))  # above the bound's 0.005


def test_the_demos_residuals_execute_the_demonstrated_actions(tmp_path):
    run = _setup(tmp_path, steps=0, prior=True)
    try:
        demos = run.prior.demos
        residual = residual_transitions(demos, run.policy)
        base_actions = residual.observations[:, -5:]
        np.testing.assert_allclose(compose(base_actions, residual.actions, run.policy.scale), demos.actions,
                                   atol=1e-5)
        # the observations are what the residual sees along the demo, memory included
        first = np.flatnonzero(demos.episode_index == demos.episode_index[0])
        state, seen = None, []
        for row in first:
            x, _, state_next = run.policy.step(demos.observations[row][None],
                                               np.zeros((1, 2), np.int64) if state is None else state)
            seen.append(x[0])
            state = state_next
        # (step by step and batched, the base's float32 products round otherwise: 2e-6 seen on the shipped clone)
        np.testing.assert_allclose(np.array(seen), residual.observations[first], atol=1e-5)
        assert run.model.replay_buffer.demos.size() == len(demos)
        # a residual that would execute the demos' actions: the critic values those, not clipped residuals
        assert np.abs(residual.actions).max() > 1.0
    finally:
        _close(run)


def test_the_actor_values_its_action_by_the_members_mean_minimum_or_lower_confidence_bound(tmp_path):
    q = torch.tensor([[[1.0], [4.0]], [[3.0], [4.0]], [[5.0], [4.0]]])  # 3 members, 2 states
    by = {}
    for mode in ("mean", "min", "lcb"):
        run = _setup(tmp_path / mode, actor_q=mode)
        try:
            assert run.model.actor_q == mode and run.config.actor_q == mode
            by[mode] = run.model.actor_value(q).flatten().tolist()
        finally:
            _close(run)
    assert by["mean"] == [3.0, 4.0] and by["min"] == [1.0, 4.0]
    assert by["lcb"] == pytest.approx([3.0 - 2.0, 4.0])  # the members' sample std: 2 where they disagree, 0 not


def test_the_advantage_weighted_actor_fits_the_actions_the_critics_prefer(tmp_path, monkeypatch):
    run = _setup(tmp_path, actor_update="awr", awr_temperature=0.5)
    try:
        model = run.model
        adv = torch.tensor([[0.0], [1.0]]).squeeze(1)  # T * mean|A| = 0.25: softmax([0, 4]) * 2
        np.testing.assert_allclose(model.awr_weights(adv).numpy(), (torch.softmax(torch.tensor([0.0, 4.0]), 0) * 2)
                                   .numpy(), rtol=1e-6)
        # critics that value a residual of +0.5 on the hand's z velocity and nothing else
        monkeypatch.setattr(model.critic, "q_values",
                            lambda obs, residual, members=None: -((residual[:, 4:5] - 0.5) ** 2).expand(2, -1, -1))
        rng = np.random.default_rng(0)
        obs = torch.as_tensor(rng.normal(0, 1, (256, run.policy.inputs.dim)), dtype=torch.float32)
        batch = type("Batch", (), {"observations": obs,
                                   "actions": torch.as_tensor(rng.uniform(-0.9, 0.9, (256, 5)), dtype=torch.float32)})
        for _ in range(300):
            model._awr_step(batch)
        with torch.no_grad():
            mean = torch.tanh(model.actor.get_action_dist_params(obs)[0]).mean(0)
        assert 0.2 < float(mean[4]) < 0.8 and float(mean[:4].abs().max()) < 0.15, mean
    finally:
        _close(run)


def test_the_ensemble_is_each_members_own_network():
    import gymnasium as gym
    from stable_baselines3.common.torch_layers import FlattenExtractor

    space = gym.spaces.Box(-np.inf, np.inf, (12,), np.float32)
    critic = EnsembleCritic(space, gym.spaces.Box(-1, 1, (5,), np.float32), [8, 8], FlattenExtractor(space), 12,
                            n_critics=3, scale=[0.5] * 5)
    obs, residual = torch.randn(7, 12), torch.rand(7, 5) * 2 - 1
    together = critic.q_values(obs, residual)
    executed = torch.clamp(obs[:, -5:] + 0.5 * residual, -1, 1)
    x = torch.cat([obs, executed], 1)
    for member in range(3):
        h = x
        layers = list(critic.q_net)
        for layer in layers:
            if hasattr(layer, "weight") and layer.weight.dim() == 3:
                h = h @ layer.weight[member] + layer.bias[member]
            else:
                h = layer(h)
        torch.testing.assert_close(together[member], h)
    chosen = torch.tensor([2, 0])  # a REDQ subset: only those members computed, the same values
    torch.testing.assert_close(critic.q_values(obs, residual, chosen), together.index_select(0, chosen))


def test_run_trains_records_and_resumes_exactly(tiny_run, tmp_path):
    run, summary = tiny_run
    assert summary["env_steps"] == TINY.steps and summary["base"] == str(SHIPPED_HIGH_LEVEL)
    assert registry.run_learner(run) == "residual-sac"  # what train --resume checks
    metrics = pd.read_csv(run / "metrics.csv")
    assert metrics["env_steps"].tolist() == [0, 120, 240]
    policy = load_policy(run / "model.zip", level="high")
    assert isinstance(policy, ResidualPolicy) and policy.hingelab_provenance["config"]["base"] == "shipped"
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    for later in ckpt.checkpoint_dirs(copy)[1:]:  # resume from the first checkpoint
        shutil.rmtree(later)
    for name in ("model.zip", "best_model.zip"):
        (copy / name).unlink()
    train_residual(TINY, copy, resume=True, progress=False)
    import io
    import zipfile

    def weights(path):
        with zipfile.ZipFile(path) as archive:
            return dict(np.load(io.BytesIO(archive.read("actor.npz"))))

    ours, theirs = weights(copy / "model.zip"), weights(run / "model.zip")
    assert ours.keys() == theirs.keys() and all(np.array_equal(ours[k], theirs[k]) for k in theirs)
    assert pd.read_csv(copy / "metrics.csv")["return"].tolist() == metrics["return"].tolist()


def test_a_training_checkpoint_loads_as_the_policy_the_run_saved_at_that_step(tiny_run, tmp_path):
    """eval high RUNDIR/checkpoints/step_N: the residual learner's SB3 training zip, read as plain tensors with
    the run's base, acts as the policy file the run wrote at the same step."""
    run, _ = tiny_run
    last = ckpt.checkpoint_dirs(run)[-1]
    assert last.name.endswith(f"{TINY.steps:012d}")
    from_checkpoint, saved = load_policy(last, level="high"), load_policy(run / "model.zip", level="high")
    assert isinstance(from_checkpoint, ResidualPolicy)
    assert from_checkpoint.hingelab_provenance["checkpoint"] == str(last.resolve())
    obs = np.random.default_rng(0).normal(0, 0.05, (64, saved.observation_dim)).astype(np.float32)
    ours, theirs = from_checkpoint.predict(obs)[0], saved.predict(obs)[0]
    np.testing.assert_array_equal(ours, theirs)
    assert np.abs(ours - saved.base.predict(obs)[0]).max() > 0  # it has learned a residual: not the base
    alone = tmp_path / "model.zip"  # outside its run folder: the base is unknown
    shutil.copy(last / "model.zip", alone)
    with pytest.raises(ConfigError, match="outside its run folder"):
        load_policy(alone, level="high")


def test_bad_input_gets_one_line_errors(tmp_path, capsys):
    with pytest.raises(ConfigError, match=r"residual scale is the largest correction .* in \(0, 1\]"):
        replace(TINY, residual_scale=(1.5,))
    with pytest.raises(ConfigError, match=r"residual scale is the largest correction"):
        replace(TINY, residual_scale=(0.0,))
    with pytest.raises(ConfigError, match="one number or 5"):
        replace(TINY, residual_scale=(0.1, 0.2))
    with pytest.raises(ConfigError, match="--exploration-bound takes 5 positive"):
        replace(TINY, exploration_bound=(0.1,))
    with pytest.raises(ConfigError, match="--base fit clones the run's privileged prior"):
        replace(TINY, base="fit", prior=False)
    # a base that learned beside another low level: refused, as eval high refuses it
    with pytest.raises(ConfigError, match="learned over the low level"):
        _setup(tmp_path, low_level=str(ASSETS_DIR / "checkpoints" / "low_level.zip"))
    with pytest.raises(ConfigError, match="not a phase-clone checkpoint"):
        _setup(tmp_path / "other", base=str(ASSETS_DIR / "checkpoints" / "low_level.zip"))
    # the run observes as its base was trained (the shipped one: the relative tool pose); told otherwise, refused
    assert TINY.env_kwargs["tool_position"] == "relative" and TINY.env_kwargs["observe_extent"] is True
    with pytest.raises(ConfigError, match="trained on the relative tool position.*gives the observed one"):
        _setup(tmp_path / "form", env_kwargs={"tool_position": "observed"})
    assert main(["train", "high", "--learner", "residual-sac", "--residual-scale", "2", "--out",
                 str(tmp_path / "cli")]) == 1
    assert "residual scale is the largest correction" in capsys.readouterr().err
    assert not (tmp_path / "cli").exists()


def test_choose_by_q_acts_with_the_residual_only_where_the_critics_prefer_it_and_saves_them(tmp_path):
    run = _setup(tmp_path, choose_by_q=True)
    try:
        model = run.model
        with torch.no_grad():  # a residual far from 0, so the two proposals differ
            model.actor.mu.bias.fill_(2.0)
        policy = run.current_policy()
        obs = np.random.default_rng(2).normal(0, 0.05, (64, policy.observation_dim)).astype(np.float32)
        x, base_action, _ = policy.step(obs, np.zeros((64, 2), np.int64))
        inputs = torch.as_tensor(x)
        residual = torch.tanh(torch.full((64, 5), 2.0))
        with torch.no_grad():  # the critics' minimum over members, for each proposal, by hand
            q_residual = model.critic.q_values(inputs, residual).min(0).values[:, 0]
            q_base = model.critic.q_values(inputs, torch.zeros_like(residual)).min(0).values[:, 0]
        wins = (q_residual > q_base).numpy()
        expected = np.where(wins[:, None], compose(base_action, residual.numpy(), policy.scale), base_action)
        np.testing.assert_allclose(policy.predict(obs)[0], expected, atol=1e-6)
        # the rollouts choose alike: SB3's sample becomes residual 0 where the base wins
        model._last_obs = x[:1]
        action, buffer_action = model._sample_action(0)
        chosen = model.chooser().wins(inputs[:1], torch.as_tensor(buffer_action)).numpy()
        assert (np.abs(buffer_action).sum() == 0) == (not chosen[0]) and np.array_equal(action, buffer_action)
        # the file carries the critics, and the loaded policy chooses as the run's did
        run.save_policy(tmp_path / "chooses.zip")
        loaded = load_policy(tmp_path / "chooses.zip", level="high")
        assert isinstance(loaded, ResidualPolicy) and loaded.chooser is not None
        np.testing.assert_array_equal(loaded.predict(obs)[0], policy.predict(obs)[0])
    finally:
        _close(run)


def test_choose_by_q_bootstraps_from_the_better_of_the_residual_and_the_base(tmp_path, monkeypatch):
    import hingelab.learners.residual.algorithm as algorithm

    run = _setup(tmp_path, choose_by_q=True)
    try:
        from stable_baselines3.common.logger import configure

        model, rng = run.model, np.random.default_rng(3)
        model.set_logger(configure(folder=None, format_strings=[]))
        dim = model.observation_space.shape[0]
        for _ in range(64):  # transitions of random inputs: the target's arithmetic is what is checked
            obs, next_obs = rng.normal(0, 1, (2, 1, dim)).astype(np.float32)
            model.replay_buffer.add(obs, next_obs, rng.uniform(-1, 1, (1, 5)).astype(np.float32),
                                    rng.normal(size=1).astype(np.float32), np.zeros(1, bool), [{}])
        targets = []
        real_mse = algorithm.F.mse_loss
        monkeypatch.setattr(algorithm.F, "mse_loss", lambda q, target: targets.append(target[0]) or real_mse(q, target))
        np.random.seed(7), torch.manual_seed(7)  # the draws the update makes, by hand, before it moves the nets
        data = model._sample(16)
        with torch.no_grad():
            next_residual, log_prob = model._action_log_prob(data.next_observations)
            chosen = torch.from_numpy(np.random.choice(model.critic.n_critics, model.target_critics, replace=False))
            q_residual = model.critic_target.q_values(data.next_observations, next_residual, chosen).min(0).values
            q_base = model.critic_target.q_values(data.next_observations, torch.zeros_like(next_residual),
                                                  chosen).min(0).values
            alpha = torch.exp(model.log_ent_coef)
            best = torch.maximum(q_residual, q_base) - alpha * log_prob.reshape(-1, 1)
            expected = data.rewards + (1 - data.dones) * model.gamma * best
        np.random.seed(7), torch.manual_seed(7)
        model.train(gradient_steps=1, batch_size=16)
        assert (q_base > q_residual).any() and (q_residual > q_base).any()  # the max picks each somewhere
        torch.testing.assert_close(targets[0], expected)
    finally:
        _close(run)
