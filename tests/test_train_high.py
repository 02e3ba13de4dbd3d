"""hingelab train high / train flat on tiny sizes: run folder, privileged prior (kept demo share,
plain pre-fill, BC term), exact resume, checkpoint records, and bad input."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch

from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError
from hingelab.learners.sac.high_level import train_high
from hingelab.learners.sac.high_level_config import FlatTrainConfig, HighLevelTrainConfig
from hingelab.training import checkpoints as ckpt

TINY = HighLevelTrainConfig(
    steps=300, n_envs=1, max_episode_steps=50, learning_starts=50, batch_size=16, buffer_size=2000, net_arch=(32, 32),
    eval_every=150, eval_episodes=1, checkpoint_every=100, keep_checkpoints=10, prior_episodes=3, demo_bc_weight=1.0,
    bc_pretrain_updates=20, bc_pretrain_std=True, demo_offline_updates=20, bc_q_scaled=True, demo_q_filter=False,
    low_level="privileged", randomize=False)


def _params(path) -> dict:
    from stable_baselines3 import SAC

    return SAC.load(path, device="cpu").policy.state_dict()


@pytest.fixture(scope="module")
def tiny_high(tmp_path_factory):
    run = tmp_path_factory.mktemp("high") / "tiny"
    return run, train_high(TINY, run, progress=False)


def test_run_writes_prior_rollouts_metrics_and_records(tiny_high):
    run, summary = tiny_high
    doc = json.loads((run / "config.json").read_text())
    assert doc["env_id"] == "hingelab/ToolPick-v0" and doc["config"]["demo_share"] == 0.5
    assert summary["env_steps"] == 300 and summary["prior"]["episodes"] == 3
    # 20 warm-up updates on the demos alone, then one per env step after learning_starts
    assert summary["updates"] == 20 + 300 - TINY.learning_starts
    prior = Dataset(run / "prior")
    assert len(prior) == 3 and (prior.index["source"] == "heuristic").all()
    metrics = pd.read_csv(run / "metrics.csv")
    assert list(metrics["env_steps"]) == [0, 150, 300]
    assert {"success_rate", "first_attempt_success_rate", "mean_attempts", "failures_tool_drop",
            "critic_loss"} <= set(metrics.columns)
    assert metrics["critic_loss"].dropna().nunique() == 3  # trained: by the warm-up, then online
    rollouts = Dataset(run / "dataset")
    assert len(rollouts) >= 300 // TINY.max_episode_steps
    assert (rollouts.index["source"] == "high_level_training").all()
    from hingelab.policies.sb3_zip import read_plain_data

    record = read_plain_data(run / "model.zip")[0]["hingelab_provenance"]
    assert record["env_id"] == "hingelab/ToolPick-v0" and record["env_kwargs"]["low_level"] == "privileged"
    assert record["env_kwargs"]["reward"]["c_h1"] == TINY.c_h1
    assert record["action_scale"] == {"z_goal": 3.0, "hand_velocity_m_s": 0.08}
    assert record["low_level_sha256"] == "privileged" and record["encoder_fingerprint"]
    assert record["prior"]["transitions"] == summary["prior"]["transitions"] > 0
    assert record["prior"]["demo_actions"] == ["recorded"]  # the scripted prior's commands
    assert Dataset(run / "prior").card.config["policy"] == "scripted"


def test_demo_share_keeps_the_demos_in_every_batch(tiny_high, tmp_path):
    """The kept demo share: the demos sit in their own store, never overwritten, and half of a batch."""
    from hingelab.learners.sac.demo_sac import DemoSAC
    from hingelab.learners.sac.high_level import HighLevelRun
    from hingelab.training.high_level_demos import DemoShareReplayBuffer

    run, summary = tiny_high
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    resumed = HighLevelRun(TINY, copy, resume=True, progress=False).setup()  # the checkpoint, read back
    resumed.env.close()
    resumed.close_evaluator()
    assert isinstance(resumed.model, DemoSAC) and resumed.model.num_timesteps == 300
    buffer = resumed.model.replay_buffer
    assert isinstance(buffer, DemoShareReplayBuffer) and buffer.demo_share == 0.5
    assert buffer.demos.size() == summary["prior"]["transitions"] and buffer.size() == 300
    batch = buffer.sample(16)
    demo_obs = buffer.demos.observations[:buffer.demos.size(), 0]
    from_demos = [bool(np.isclose(demo_obs, o.numpy()).all(axis=1).any()) for o in batch.observations]
    assert sum(from_demos[:8]) == 8  # the first half of a batch comes from the demos


def test_resume_continues_exactly(tiny_high, tmp_path):
    run, _ = tiny_high
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    for later in ckpt.checkpoint_dirs(copy)[1:]:  # keep the checkpoint of step 100 (or 200) only
        shutil.rmtree(later)
    for name in ("model.zip", "best_model.zip"):
        (copy / name).unlink()
    train_high(TINY, copy, resume=True, progress=False)
    ours, theirs = _params(copy / "model.zip"), _params(run / "model.zip")
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)
    assert pd.read_csv(copy / "metrics.csv")["return"].tolist() == pd.read_csv(run / "metrics.csv")["return"].tolist()


def test_plain_prefill_goes_through_the_ring_buffer(tmp_path):
    """--demo-share 0: the paper's plain pre-fill, here of the paper's heuristic demos (reached latents)."""
    from hingelab.learners.sac.high_level import HighLevelRun

    config = replace(TINY, demo_share=0.0, steps=0, demo_bc_weight=0.0, bc_pretrain_updates=0,
                     prior_source="heuristic", prior_episodes=2)
    run = HighLevelRun(config, tmp_path / "plain", progress=False).setup()
    try:
        assert run.prior.info["demo_actions"] == ["reached"]
        assert Dataset(tmp_path / "plain" / "prior").card.config.get("policy") is None  # generate heuristic's
        assert type(run.model.replay_buffer).__name__ == "ReplayBuffer"
        assert run.model.replay_buffer.size() == run.prior.info["transitions"] > 0
        assert type(run.model).__name__ == "FastSAC"
    finally:
        run.env.close()
        run.close_evaluator()


def test_flat_baseline_trains_on_its_own_env(tmp_path):
    config = FlatTrainConfig(steps=120, n_envs=1, max_episode_steps=30, learning_starts=30, batch_size=16,
                             buffer_size=1000, net_arch=(16,), eval_every=120, eval_episodes=1, checkpoint_every=60,
                             randomize=False)
    summary = train_high(config, tmp_path / "flat", progress=False)
    assert summary["env_steps"] == 120 and summary["prior"] is None
    rollouts = Dataset(tmp_path / "flat" / "dataset")
    assert (rollouts.index["source"] == "flat_training").all()
    import gymnasium as gym

    from hingelab.envs import TOOL_PICK_FLAT_ID
    from hingelab.policies.sb3_zip import load_sac_zip

    env = gym.make(TOOL_PICK_FLAT_ID)
    model = load_sac_zip(tmp_path / "flat" / "model.zip", env.observation_space, env.action_space)  # the env's spaces
    env.close()
    assert model.action_space.shape == (12,) and model.hingelab_provenance["env_id"] == "hingelab/ToolPickFlat-v0"
    with pytest.raises(ConfigError, match="flat baseline learns without demonstrations"):
        replace(config, from_datasets=("x",))


def test_high_level_checkpoint_is_refused_beside_another_low_level(tiny_high):
    from hingelab.policies.high_level import load_high_level_checkpoint

    run, _ = tiny_high
    assert load_high_level_checkpoint(run / "model.zip", low_level="privileged") is not None
    with pytest.raises(ConfigError, match="learned over the low level privileged"):
        load_high_level_checkpoint(run / "model.zip", low_level="policy")
    # a policy learned over the shipped low level is refused over another trained one, not over the servo
    from hingelab.policies.high_level import check_context, training_context
    from hingelab.policies.low_level import SHIPPED_LOW_LEVEL_SAC

    model = load_high_level_checkpoint(run / "model.zip")
    model.hingelab_provenance = {**model.hingelab_provenance, **training_context("policy")}
    check_context(model, "x.zip", "privileged")
    with pytest.raises(ConfigError, match="learned over the low level policy"):
        check_context(model, "x.zip", str(SHIPPED_LOW_LEVEL_SAC))


def test_bad_input_gets_one_line_errors(tmp_path):
    with pytest.raises(ConfigError, match="--no-prior"):
        replace(TINY, prior=False, from_datasets=("x",))
    no_prior = replace(TINY, prior=False)  # no demos: nothing to clone or warm up on
    assert (no_prior.demo_bc_weight, no_prior.bc_pretrain_updates, no_prior.demo_offline_updates) == (0, 0, 0)
    with pytest.raises(ConfigError, match="does not exist"):
        train_high(replace(TINY, low_level=str(tmp_path / "nowhere.zip")), tmp_path / "a", progress=False)
    assert not (tmp_path / "a").exists()  # nothing written for a bad input
    with pytest.raises(ConfigError, match="does not exist"):
        train_high(replace(TINY, from_datasets=(str(tmp_path / "none"),)), tmp_path / "b", progress=False)
    with pytest.raises(ConfigError, match="unknown object"):
        train_high(replace(TINY, object="pyramid", prior=False), tmp_path / "c", progress=False)
    import gymnasium as gym

    env = gym.make("hingelab/ToolPick-v0", low_level="privileged")
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="finite values"):  # NaN actions: a one-line error, not a NaN sim
        env.step(np.full(5, np.nan, np.float32))
    env.close()
    with pytest.raises(ConfigError, match="demo_share"):
        replace(TINY, demo_share=1.5)


def test_cli_flags_come_from_the_config(capsys):
    from hingelab.cli.main import build_parser

    parser = build_parser([])
    args = parser.parse_args(["train", "high", "--gamma", "0.95", "--net-arch", "64", "64", "--no-prior",
                              "--c-h1", "50", "--demo-share", "0"])
    from hingelab.training.run_config import config_from_args

    config = config_from_args(args.learner_class.config_class, args)
    assert config.gamma == 0.95 and config.net_arch == (64, 64) and not config.prior and config.c_h1 == 50
    assert config.reward.c_h1 == 50
    flat = parser.parse_args(["train", "flat", "--tau", "0.01"])
    assert config_from_args(flat.learner_class.config_class, flat).tau == 0.01
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "flat", "--from", "x"])
    # a negating flag and its opposite: the high level's default is no Q-filter
    on = parser.parse_args(["train", "high", "--demo-q-filter"])
    assert config_from_args(on.learner_class.config_class, on).demo_q_filter is True
    assert parser.parse_args(["train", "low", "--bc-no-q-filter"]).demo_q_filter is False
    from hingelab.learners.sac.low_level_config import LowLevelTrainConfig

    # a flag not given stays out of the parsed args (a --resume tells it from a default) ...
    assert not hasattr(parser.parse_args(["train", "low"]), "demo_q_filter")
    # ... and the config has the low level's default
    assert config_from_args(LowLevelTrainConfig, parser.parse_args(["train", "low"])).demo_q_filter is True
    assert parser.parse_args(["train", "low", "--no-effort"]).use_effort is False


def test_pretraining_fits_the_spread_too(tiny_high):
    """--bc-pretrain-std: the actor's spread shrinks toward the demonstrations' (it starts near 1)."""
    from hingelab.learners.sac.demo_sac import Demonstrations, DemoSAC
    from hingelab.training.high_level_demos import high_level_transitions

    run, _ = tiny_high
    demos = Demonstrations.from_transitions(high_level_transitions([run / "prior"], actions="recorded"))
    spreads = {}
    for fit_std in (False, True):
        model = DemoSAC.load(run / "model.zip", device="cpu")
        model.set_demonstrations(demos)
        model.pretrain_actor(1500, batch_size=32, fit_std=fit_std)
        _, log_std, _ = model.actor.get_action_dist_params(demos.observations[:64])
        spreads[fit_std] = float(log_std.mean())
    assert spreads[True] < spreads[False] - 0.3, spreads


def test_train_flat_runs_from_the_command_line(tmp_path, capsys):
    from hingelab.cli.main import main

    out = tmp_path / "flat"
    assert main(["train", "flat", "--steps", "60", "--envs", "1", "--max-episode-steps", "30", "--learning-starts",
                 "30", "--batch-size", "16", "--buffer-size", "500", "--net-arch", "16", "--eval-every", "60",
                 "--eval-episodes", "1", "--checkpoint-every", "60", "--no-randomize", "--out", str(out),
                 "--no-progress"]) == 0
    assert "Trained the flat baseline to 60 env steps" in capsys.readouterr().out
    assert json.loads((out / "config.json").read_text())["env_id"] == "hingelab/ToolPickFlat-v0"


def test_prior_over_all_pick_sets(tmp_path):
    """--prior-objects all: one prior dataset per shape and size, all of them in the demos."""
    config = replace(TINY, steps=60, eval_every=60, checkpoint_every=60, prior_objects="all", prior_episodes=12,
                     prior_source="scripted-feedback", max_episode_steps=20, bc_pretrain_updates=5,
                     demo_offline_updates=0)
    summary = train_high(config, tmp_path / "all", progress=False)
    folders = sorted(p.name for p in (tmp_path / "all" / "prior").iterdir())
    assert len(folders) == 12 and "tetrahedron_2.5cm" in folders
    assert summary["prior"]["episodes"] == 12 and summary["prior"]["demo_actions"] == ["recorded"] * 12
    cards = [Dataset(tmp_path / "all" / "prior" / f).card for f in folders]
    assert {c.config["policy"] for c in cards} == {"scripted-feedback"}
    assert sorted((c.config["object"], c.config["size"]) for c in cards)[0] == ("cube", 0.015)


def test_a_start_that_failed_before_its_first_step_runs_again(tmp_path, capsys):
    """A bad --from fails after config.json is written; the same command again gives the same one-line
    error, not 'already holds a run' (a --resume would fail alike), and a started run is still refused."""
    from hingelab.cli.main import main
    from hingelab.training.run_folder import has_started

    typo = tmp_path / "demos_typo"
    typo.mkdir()
    out = tmp_path / "run"
    args = ["train", "high", "--from", str(typo), "--steps", "60", "--out", str(out), "--no-progress"]
    for _ in range(2):
        assert main(args) != 0
        err = capsys.readouterr().err.strip()
        assert "not a hingelab dataset" in err and "already holds a run" not in err and "\n" not in err
    assert (out / "config.json").exists() and not has_started(out)
    (out / "metrics.csv").write_text("env_steps\n0\n")  # it evaluated once: a started run
    assert has_started(out)
    assert main(args) != 0 and "already holds a run" in capsys.readouterr().err
