"""FastSAC(update="fused") is SB3's SAC update with the gradients written out by hand: the same weights and
losses as SB3 after a few hundred updates from the same start and batches (twin critics and an ensemble),
the model's own Adam states, saves that load as SB3 SAC and a resume that continues exactly. Tiny nets."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.logger import configure

from hingelab.bench.sac import make_filled_model
from hingelab.learners.sac.fast_sac import FastSAC
from hingelab.learners.sac.fused_update import FusedSACUpdate

NET = dict(net_arch=[32, 32])
BATCH = 64
CALLS, UPDATES_PER_CALL = 6, 50  # 300 updates


def _filled(cls, seed=0, policy_kwargs=None, **kwargs):
    """A model on the bench's goal-env shapes, a 500-row buffer of fixed noise (the same for every seed)."""
    return make_filled_model(cls, seed, buffer_size=500, batch_size=BATCH, noise_seed=0, done_rate=0.05,
                             policy_kwargs=dict(policy_kwargs or NET), **kwargs)


def _losses(model):
    values = model.logger.name_to_value
    return np.array([values[k] for k in ("train/critic_loss", "train/actor_loss", "train/ent_coef_loss",
                                         "train/ent_coef")])


def train_pair(reference, fused, calls=CALLS):
    """``calls`` x 50 updates of both models on the same batches and noise; the losses logged after each call."""
    losses = []
    for call in range(calls):
        pair = []
        for model in (reference, fused):
            th.manual_seed(100 + call)  # the same actor noise ...
            np.random.seed(100 + call)  # ... and the same batches
            model.train(gradient_steps=UPDATES_PER_CALL, batch_size=BATCH)
            pair.append(_losses(model))
        losses.append(pair)
    return losses


def _same_start(reference, fused):
    fused.policy.load_state_dict(reference.policy.state_dict())
    fused.log_ent_coef.data.copy_(reference.log_ent_coef.data)


def _assert_same_models(ours_model, theirs_model, rtol=2e-3, atol=2e-4):
    theirs = dict(theirs_model.policy.named_parameters())
    for name, ours in ours_model.policy.named_parameters():
        th.testing.assert_close(ours, theirs[name], rtol=rtol, atol=atol, msg=name)
    theirs = dict(theirs_model.critic_target.named_parameters())
    for name, ours in ours_model.critic_target.named_parameters():
        th.testing.assert_close(ours, theirs[name], rtol=rtol, atol=atol, msg=name)
    th.testing.assert_close(ours_model.log_ent_coef, theirs_model.log_ent_coef, rtol=1e-4, atol=1e-5)


@pytest.fixture(scope="module")
def trained_pair():
    """SB3 SAC and FastSAC(update="fused") from the same weights, 300 updates on the same batches and noise."""
    sb3 = _filled(SAC, seed=1)
    fused = _filled(FastSAC, seed=2, update="fused")
    _same_start(sb3, fused)
    return sb3, fused, train_pair(sb3, fused)


def test_fused_update_agrees_with_sb3_sac_over_300_updates(trained_pair):
    sb3, fused, losses = trained_pair
    assert isinstance(fused._fused_update, FusedSACUpdate)  # the fused path ran
    for theirs, ours in losses:
        np.testing.assert_allclose(ours, theirs, rtol=2e-3, atol=2e-4)
    _assert_same_models(fused, sb3)
    assert fused._n_updates == sb3._n_updates == CALLS * UPDATES_PER_CALL
    assert not th.allclose(fused.actor.mu.weight, _filled(SAC, seed=1).actor.mu.weight)  # it did learn


def test_fused_update_of_a_ten_critic_ensemble_and_tanh_agrees_with_the_eager_update():
    kwargs = dict(net_arch=[32, 32], n_critics=10, activation_fn=th.nn.Tanh)
    eager = _filled(FastSAC, seed=1, policy_kwargs=kwargs)
    fused = _filled(FastSAC, seed=2, policy_kwargs=kwargs, update="fused")
    _same_start(eager, fused)
    losses = train_pair(eager, fused, calls=2)
    for theirs, ours in losses:
        np.testing.assert_allclose(ours, theirs, rtol=2e-3, atol=2e-4)
    _assert_same_models(fused, eager)
    assert fused._fused_update.critic.weights[1].shape == (10, 32, 32)  # one stack, not ten networks


def test_fused_update_keeps_the_models_adam_states_and_saves_as_sb3_sac(trained_pair, tmp_path):
    sb3, fused, _ = trained_pair
    for optimizer, reference in ((fused.actor.optimizer, sb3.actor.optimizer),
                                 (fused.critic.optimizer, sb3.critic.optimizer),
                                 (fused.ent_coef_optimizer, sb3.ent_coef_optimizer)):
        for p, q in zip(optimizer.param_groups[0]["params"], reference.param_groups[0]["params"]):
            ours, theirs = optimizer.state[p], reference.state[q]
            assert float(ours["step"]) == float(theirs["step"]) == CALLS * UPDATES_PER_CALL
            th.testing.assert_close(ours["exp_avg_sq"], theirs["exp_avg_sq"], rtol=2e-2, atol=1e-6)
    fused.save(tmp_path / "model.zip")
    loaded = SAC.load(tmp_path / "model.zip")
    for (name, a), b in zip(fused.policy.state_dict().items(), loaded.policy.state_dict().values()):
        th.testing.assert_close(a, b, msg=name)


def test_a_fused_model_resumed_from_its_save_continues_exactly(tmp_path):
    """Save after 100 updates, load, go on: the same weights as the model that never stopped (load copies
    into the stacked parameters in place, so the fused update keeps its views)."""
    straight = _filled(FastSAC, seed=3, update="fused")
    straight.train(gradient_steps=100, batch_size=BATCH)
    straight.save(tmp_path / "model.zip")
    straight.save_replay_buffer(tmp_path / "buffer.pkl")
    resumed = FastSAC.load(tmp_path / "model.zip")
    resumed.load_replay_buffer(tmp_path / "buffer.pkl")
    resumed.set_logger(configure(None, []))
    for model in (straight, resumed):
        th.manual_seed(7)
        np.random.seed(7)
        model.train(gradient_steps=50, batch_size=BATCH)
    _assert_same_models(resumed, straight, rtol=0, atol=0)
    assert resumed.update == "fused" and resumed._fused_update.intact()


def test_switching_between_the_eager_and_the_fused_update_keeps_one_model():
    """The eager update's zero_grad unsets the .grad views and an outside .data assignment cuts a parameter
    loose: the fused update re-attaches its gradients, and rebuilds its stacks when the views are gone."""
    model = _filled(FastSAC, seed=4, update="fused")
    model.train(gradient_steps=5, batch_size=BATCH)
    first = model._fused_update
    model.update = "eager"
    model.train(gradient_steps=5, batch_size=BATCH)
    model.update = "fused"
    model.train(gradient_steps=5, batch_size=BATCH)
    assert model._fused_update is first and first.intact()
    model.actor.mu.weight.data = model.actor.mu.weight.data.clone()
    model.train(gradient_steps=5, batch_size=BATCH)
    assert model._fused_update is not first and model._fused_update.intact()
    assert model._n_updates == 20


def test_models_the_fused_update_cannot_run_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="fixed ent_coef"):
        _filled(FastSAC, seed=0, ent_coef=0.1, update="fused")
    with pytest.raises(ValueError, match="'eager', 'compiled', 'fused'"):
        _filled(FastSAC, seed=0, update="jit")


# --- bench sac's fused arm and the matmul floor ------------------------------------------------------


def test_bench_table_ratios_of_the_fused_arm_and_the_matmul_floor():
    from hingelab.bench.sac import BASELINE, COMPILED, FUSED, MATMULS, OURS, SBX, build_table

    rates = {1: {BASELINE: [50.0, 60.0, 40.0], OURS: [66.0, 64.0, 80.0], COMPILED: [90.0, 80.0, 85.0],
                 FUSED: [95.0, 92.0, 99.0], MATMULS: [120.0, 130.0, 110.0], SBX: [100.0, 70.0, 80.0]}}
    config = {"stable_baselines3": "x", "torch": "y", "batch_size": 256, "buffer_size": 100, "rounds": 3,
              "updates_per_block": 10, "profile_updates": 10, "sbx": "0.28.0", "jax": "0.10.2"}
    table = build_table(rates, {}, config)
    rows = {r["config"]: r for r in table.rows}
    assert rows[FUSED]["role"] == "ours, update by hand" and rows[MATMULS]["role"].startswith("diagnostic")
    assert table.ratios[f"updates/s {FUSED} / {SBX}, 1 thread (target: >= 1.0)"] == pytest.approx(95.0 / 80.0)
    assert table.ratios[f"updates/s {FUSED} / {COMPILED}, 1 thread"] == pytest.approx(95.0 / 85.0)
    floor = next(value for name, value in table.ratios.items() if name.startswith(f"{MATMULS} per s / {SBX}"))
    assert floor == pytest.approx(120.0 / 80.0)


def test_the_matmul_floor_runs_the_products_of_one_update():
    """602.9 MFLOP on the bench's shapes: 16 products of 256 x 256 x 256 (33.6 MFLOP each) and the thin ones."""
    from hingelab.bench.sac import UpdateMatmuls

    floor = UpdateMatmuls()
    assert floor.flops == 602_931_200
    assert len(floor.products) == 3 + 9 + 5 + 3 + 5
    floor.train(gradient_steps=1)
    x, y, out = floor.products[4]
    th.testing.assert_close(out, th.bmm(x, y))
    # ten critics: the critics' 448 MFLOP five times, the actor's 155 once (what the ensemble bench meets)
    assert UpdateMatmuls(critics=10).flops == pytest.approx(3.97 * floor.flops, rel=0.01)


def test_bench_ensemble_counts_the_products_the_residual_learner_computes():
    """REDQ's target computes a pair whatever the ensemble: 10 critics cost 3.46x the twin critics' products, so
    issue 43's 1.6x would need three quarters of the twin-critic update outside its products."""
    from hingelab.bench.ensemble import product_flops

    flops = product_flops()
    assert flops[2] < flops[5] < flops[10]
    assert flops[10] / flops[2] == pytest.approx(3.46, abs=0.01)
