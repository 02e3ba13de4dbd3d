"""FastSAC(update="compiled") is SB3's SAC update as one compiled function: the same weights and losses
as SB3 after a few hundred updates from the same start and batches, the model's own optimizer states
kept, saves that load as SB3 SAC; and bench sac's table with the compiled and SBX arms. Tiny nets; one
torch.compile (~20-40 s) shared by the module."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from tests.test_fused_update import train_pair

from hingelab.bench.sac import BASELINE, COMPILED, OURS, SBX, build_table, dummy_goal_env, make_filled_model, ratio_name
from hingelab.learners.sac.compiled_update import CompiledSACUpdate
from hingelab.learners.sac.fast_sac import FastSAC

NET = dict(net_arch=[32, 32])
BATCH = 64
CALLS, UPDATES_PER_CALL = 6, 50  # 300 updates


def _filled(cls, seed=0, **kwargs):
    """A model on the bench's goal-env shapes, a 500-row buffer of fixed noise (the same for every seed)."""
    return make_filled_model(cls, seed, buffer_size=500, batch_size=BATCH, noise_seed=0, done_rate=0.05,
                             policy_kwargs=dict(NET), **kwargs)


@pytest.fixture(scope="module")
def trained_pair():
    """SB3 SAC and FastSAC(update="compiled") from the same weights, 300 updates on the same batches and noise;
    the losses each logged after every 50."""
    sb3 = _filled(SAC, seed=1)
    compiled = _filled(FastSAC, seed=2, update="compiled")
    compiled.policy.load_state_dict(sb3.policy.state_dict())
    compiled.log_ent_coef.data.copy_(sb3.log_ent_coef.data)
    losses = train_pair(sb3, compiled)
    return sb3, compiled, losses


def test_compiled_update_agrees_with_sb3_sac_over_300_updates(trained_pair):
    sb3, compiled, losses = trained_pair
    assert isinstance(compiled._compiled_update, CompiledSACUpdate)  # the compiled path ran
    for ours, theirs in ((o, t) for t, o in losses):
        np.testing.assert_allclose(ours, theirs, rtol=2e-3, atol=2e-4)
    theirs = dict(sb3.policy.named_parameters())
    for name, ours in compiled.policy.named_parameters():
        th.testing.assert_close(ours, theirs[name], rtol=1e-3, atol=1e-3, msg=name)
    for name, ours in compiled.critic_target.named_parameters():
        th.testing.assert_close(ours, dict(sb3.critic_target.named_parameters())[name], rtol=1e-3, atol=1e-3)
    th.testing.assert_close(compiled.log_ent_coef, sb3.log_ent_coef, rtol=1e-4, atol=1e-5)
    assert compiled._n_updates == sb3._n_updates == CALLS * UPDATES_PER_CALL
    # the weights moved: agreement is not both standing still
    assert not th.allclose(compiled.actor.mu.weight, _filled(SAC, seed=1).actor.mu.weight)


def test_compiled_update_keeps_the_models_adam_states(trained_pair, tmp_path):
    """The optimizers' moments and step counts are the model's own, as after eager Adam steps, so a save
    loads as plain SB3 SAC with its optimizers and training can go on eager."""
    sb3, compiled, _ = trained_pair
    for optimizer, reference in ((compiled.actor.optimizer, sb3.actor.optimizer),
                                 (compiled.critic.optimizer, sb3.critic.optimizer),
                                 (compiled.ent_coef_optimizer, sb3.ent_coef_optimizer)):
        ours, theirs = optimizer.state_dict()["state"], reference.state_dict()["state"]
        assert set(ours) == set(theirs)
        for index, state in ours.items():
            assert float(state["step"]) == float(theirs[index]["step"]) == CALLS * UPDATES_PER_CALL
            th.testing.assert_close(state["exp_avg"], theirs[index]["exp_avg"], rtol=1e-2, atol=1e-3)
            th.testing.assert_close(state["exp_avg_sq"], theirs[index]["exp_avg_sq"], rtol=1e-2, atol=1e-5)
    compiled.save(tmp_path / "model.zip")
    loaded = SAC.load(tmp_path / "model.zip", device="cpu")
    for (name, a), b in zip(compiled.policy.state_dict().items(), loaded.policy.state_dict().values()):
        assert th.equal(a, b), name
    eager = FastSAC.load(tmp_path / "model.zip", device="cpu", custom_objects={"update": "eager"})
    assert eager.update == "eager"


def test_unsupported_models_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="fixed ent_coef"):
        FastSAC("MultiInputPolicy", dummy_goal_env(), policy_kwargs=dict(NET), ent_coef=0.1, update="compiled",
                device="cpu")
    with pytest.raises(ValueError, match="'eager', 'compiled', 'fused'"):
        FastSAC("MultiInputPolicy", dummy_goal_env(), policy_kwargs=dict(NET), update="jit", device="cpu")


# --- bench sac's table with the compiled and SBX arms ----------------------------------------------


def _config(**extra):
    return {"stable_baselines3": "x", "torch": "y", "batch_size": 256, "buffer_size": 100, "rounds": 3,
            "updates_per_block": 10, "profile_updates": 10, **extra}


def test_bench_table_ratios_of_the_compiled_and_sbx_arms():
    rates = {1: {BASELINE: [50.0, 60.0, 40.0], OURS: [66.0, 64.0, 80.0], COMPILED: [90.0, 80.0, 85.0],
                 SBX: [100.0, 70.0, 80.0]},
             2: {BASELINE: [90.0, 80.0, 100.0], OURS: [110.0, 120.0, 100.0], COMPILED: [150.0, 140.0, 130.0]}}
    table = build_table(rates, {}, _config(sbx="0.28.0", jax="0.10.2"))
    rows = {(r["threads"], r["config"]): r for r in table.rows}
    assert set(rows) == {(t, arm) for t, arms in rates.items() for arm in arms}  # SBX at 1 thread only
    assert rows[(1, SBX)]["role"].startswith("compiled baseline") and rows[(1, COMPILED)]["updates/s"] == 85.0
    assert list(table.ratios)[0] == ratio_name(1)
    assert table.ratios[f"updates/s {COMPILED} / {SBX}, 1 thread (target: >= 1.0)"] == pytest.approx(85.0 / 80.0)
    assert table.ratios[f"updates/s {OURS} / {SBX}, 1 thread"] == pytest.approx(66.0 / 80.0)
    assert table.ratios[f"updates/s {COMPILED} / {OURS}, 2 threads (the compiled update alone)"] == \
        pytest.approx(140.0 / 110.0)
    assert not any(SBX in name and "2 threads" in name for name in table.ratios)
    assert any("sbx-rl 0.28.0 on jax 0.10.2" in note for note in table.notes)


def test_bench_table_says_when_sbx_was_not_installed():
    rates = {1: {BASELINE: [50.0], OURS: [60.0], COMPILED: [70.0]}}
    table = build_table(rates, {}, _config(sbx=None, jax=None))
    assert not any(SBX in name for name in table.ratios)
    assert any(note.startswith(f"{SBX}: not measured: sbx is not installed") for note in table.notes)


def test_train_commands_take_the_compiled_and_fused_updates_and_refuse_what_they_cannot_run():
    """`train low|high|flat --update compiled|fused` reaches FastSAC (the updates' arithmetic is tested above and
    in test_fused_update); configs they cannot run are refused in one line at the door, before a run folder exists."""
    from hingelab.errors import ConfigError
    from hingelab.learners.residual.config import ResidualSACConfig
    from hingelab.learners.sac.high_level_config import FlatTrainConfig, HighLevelTrainConfig
    from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
    from hingelab.learners.sac.run import sac_arguments

    assert "update" not in sac_arguments(LowLevelTrainConfig())  # eager: FastSAC's default, saved zips unchanged
    for update in ("compiled", "fused"):
        for config in (LowLevelTrainConfig(update=update), HighLevelTrainConfig(update=update, prior=False),
                       FlatTrainConfig(update=update)):
            assert sac_arguments(config)["update"] == update
        for kwargs, reason in (({"algorithm": "sac"}, "fast_sac's"), ({"ent_coef": "0.1"}, "--ent-coef auto"),
                               ({"demo_bc_weight": 1.0}, "no BC term")):
            with pytest.raises(ConfigError, match=f"--update {update} cannot run this config: .*{reason}"):
                LowLevelTrainConfig(update=update, **kwargs)
        with pytest.raises(ConfigError, match="its own update"):
            ResidualSACConfig(update=update)
