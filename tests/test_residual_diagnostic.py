"""hingelab diagnose residual: true discounted values by hand, zeroing a residual's action group, the verdict's
two causes, and the command on a tiny residual run's checkpoint."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.learners.residual.config import ResidualSACConfig
from hingelab.learners.residual.run import train_residual
from hingelab.policies import load_policy
from hingelab.rollouts import residual_diagnostic as rd
from hingelab.training import checkpoints as ckpt


def test_discounted_values_bootstrap_a_time_limit_cut_but_not_a_termination():
    gamma = 0.5
    ended = rd.discounted_values([1.0, 2.0, 4.0], truncated=False, gamma=gamma)
    np.testing.assert_allclose(ended, [1 + 0.5 * 2 + 0.25 * 4, 2 + 0.5 * 4, 4])
    cut = rd.discounted_values([1.0, 2.0, 4.0], truncated=True, gamma=gamma)
    held = 4 / (1 - gamma)  # the last reward forever, the critic's fixed point at a cut
    np.testing.assert_allclose(cut, [1 + 0.5 * 2 + 0.25 * held, 2 + 0.5 * held, held])


def _summary(base_picks, residual_picks, dv, se=1.0, best="velocity_z", best_picks=None):
    rows = [{"arm": "base", "episodes": 30, "successes": base_picks, "v0": 50.0, "v0_minus_base": 0.0,
             "v0_minus_base_se": 0.0},
            {"arm": "residual", "episodes": 30, "successes": residual_picks, "v0": 50.0 + dv, "v0_minus_base": dv,
             "v0_minus_base_se": se}]
    for name in rd.GROUPS:
        picks = best_picks if name == best and best_picks is not None else residual_picks
        rows.append({"arm": f"residual without {name}", "episodes": 30, "successes": picks, "v0": 50.0,
                     "v0_minus_base": 0.0, "v0_minus_base_se": se})
    return rows


def test_the_verdict_tells_the_learner_from_the_reward():
    assert "fix the learner" in rd.verdict(_summary(18, 12, dv=-4.6, best_picks=17))
    assert "Zeroing velocity_z recovers the most: 17" in rd.verdict(_summary(18, 12, dv=-4.6, best_picks=17))
    assert "fix the reward" in rd.verdict(_summary(18, 12, dv=+5.0))
    assert "without a measurable change" in rd.verdict(_summary(18, 12, dv=+1.0))
    assert "does not cost picks" in rd.verdict(_summary(18, 20, dv=-5.0))


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    config = ResidualSACConfig(
        steps=160, n_envs=1, max_episode_steps=40, learning_starts=40, actor_start=80, batch_size=16,
        buffer_size=1000, net_arch=(32, 32), critics=2, eval_every=160, eval_episodes=1, checkpoint_every=160,
        prior=False, low_level="privileged", randomize=False)
    run = tmp_path_factory.mktemp("residual") / "run"
    train_residual(config, run, progress=False)
    return ckpt.checkpoint_dirs(run)[-1]


def test_zeroing_a_group_acts_as_the_base_on_it_and_as_the_residual_elsewhere(tiny_checkpoint):
    policy = load_policy(tiny_checkpoint, level="high")
    obs = np.random.default_rng(0).normal(0, 0.05, (32, policy.observation_dim)).astype(np.float32)
    full, base = policy.predict(obs)[0], policy.base.predict(obs)[0]
    masked = rd.without(policy, rd.GROUPS["velocity_z"]).predict(obs)[0]
    np.testing.assert_array_equal(masked[:, 4], base[:, 4])
    np.testing.assert_array_equal(masked[:, :4], full[:, :4])
    assert np.array_equal(policy.predict(obs)[0], full)  # the original is untouched


def test_diagnose_residual_writes_its_table_and_verdict(tiny_checkpoint, tmp_path, capsys):
    out = tmp_path / "diag"
    assert main(["diagnose", "residual", str(tiny_checkpoint), "--episodes", "2", "--seed", "3", "--out", str(out),
                 "--allow-dirty", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "base:" in printed and "residual without velocity_z:" in printed
    report = (out / "residual_diagnostic.md").read_text()
    assert "| residual |" in report and "The residual picks" in report
    rows = pd.read_csv(out / "episodes.csv")
    assert sorted(rows["arm"].unique()) == sorted(["base", "residual", *(f"residual without {g}" for g in rd.GROUPS)])
    assert (rows.groupby("arm")["seed"].apply(list).apply(tuple).nunique()) == 1  # the same starts in every arm


def test_a_policy_that_is_not_a_residual_is_refused(tmp_path, capsys):
    from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL

    assert main(["diagnose", "residual", str(SHIPPED_HIGH_LEVEL), "--out", str(tmp_path / "d"), "--allow-dirty"]) != 0
    assert "is not a residual policy" in capsys.readouterr().err


def test_bias_tolerance_offsets_one_dimension_both_ways_and_reads_the_tolerated_level(tmp_path, capsys, monkeypatch):
    from hingelab.rollouts import bias_tolerance as bt

    made = []  # the env observes as the shipped policy was trained: the extent and the relative tool pose
    make = bt.gym.make
    monkeypatch.setattr(bt.gym, "make", lambda *a, **kw: made.append(kw) or make(*a, **kw))

    rows = [{"dimension": "none", "offset": 0.0, "episodes": 10, "successes": 9, "tool_drops": 0}]
    for offset, picks in ((-0.05, 3), (-0.01, 9), (0.01, 8), (0.05, 9)):
        rows.append({"dimension": "velocity_z", "offset": offset, "episodes": 10, "successes": picks, "tool_drops": 0})
    assert bt.tolerances(rows) == {"velocity_z": 0.01}  # -0.05 picks 3 of 10: below 0.9 - 0.1
    out = tmp_path / "bias"
    assert main(["diagnose", "bias", "--episodes", "1", "--levels", "0.05", "--dimensions", "velocity_z",
                 "--seed", "3", "--out", str(out), "--allow-dirty", "--no-progress"]) == 0
    measured = pd.read_csv(out / "bias_tolerance.csv")
    assert measured["offset"].tolist() == [0.0, -0.05, 0.05] and (measured["episodes"] == 1).all()
    assert "| velocity_z |" in (out / "bias_tolerance.md").read_text()
    assert "velocity_z: tolerates an offset of" in capsys.readouterr().out
    assert made and made[0]["observe_extent"] is True and made[0]["tool_position"] == "relative"
