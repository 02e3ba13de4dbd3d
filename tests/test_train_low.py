"""hingelab train low / eval low on tiny sizes: files written, losses moving, exact resume,
replay pre-fill from MCAP, offline training, parallel envs and bad input."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch

from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.errors import ConfigError
from hingelab.learners.sac.low_level import train_low
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
from hingelab.training import checkpoints as ckpt

TINY = LowLevelTrainConfig(
    steps=120, n_envs=1, max_episode_steps=10, learning_starts=30, batch_size=16, buffer_size=2000,
    eval_every=60, eval_goals_per_region=1, checkpoint_every=30, keep_checkpoints=10, algorithm="sac",
)


def _params(path) -> dict:
    from stable_baselines3 import SAC

    return SAC.load(path, device="cpu").policy.state_dict()


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("runs") / "tiny"
    summary = train_low(TINY, run, progress=False)
    return run, summary


def test_run_writes_config_metrics_rollouts_checkpoints(tiny_run):
    run, summary = tiny_run
    doc = json.loads((run / "config.json").read_text())
    assert doc["config"]["seed"] == 0 and doc["env_id"] == "hingelab/ToolShape-v0"
    assert "git_commit" in doc and "hingelab_version" in doc
    metrics = pd.read_csv(run / "metrics.csv")
    assert list(metrics["env_steps"]) == [0, 60, 120]
    assert {"success_rate", "return", "final_latent_distance", "tool_drift_mm_max", "last_step_success_rate",
            "settled_latent_distance"} <= set(metrics.columns)
    assert "settled_success_rate" not in metrics.columns  # one verdict: success_rate is the settled one
    # the critic is being trained: its loss is logged and changes between evaluations
    losses = metrics["critic_loss"].dropna()
    assert len(losses) == 2 and losses.iloc[0] != losses.iloc[1]
    assert summary["env_steps"] == 120 and summary["updates"] == 120 - TINY.learning_starts
    # every finished training episode is an MCAP episode of the run's dataset
    dataset = Dataset(run / "dataset")
    assert len(dataset) >= 120 // TINY.max_episode_steps
    assert (dataset.index["source"] == "low_level_training").all()
    assert (dataset.index["success_verdict"] == "settled_0.5s").all()
    assert dataset.index["last_step_success"].notna().all()
    # SB3's rollout success (info["is_success"] of every finished episode) counts what the episodes record
    assert metrics["rollout_success_rate"].iloc[-1] == pytest.approx(dataset.index["success"].astype(float).mean())
    assert dataset.index["length"].sum() - len(dataset) <= 120  # steps (+1 reset row each) of finished episodes
    assert ckpt.latest_checkpoint(run).name == "step_000000000120"
    state = ckpt.read_state(ckpt.latest_checkpoint(run))
    assert state["model"]["num_timesteps"] == 120
    from stable_baselines3 import SAC

    model = SAC.load(run / "model.zip")
    assert model.hingelab_provenance["config"]["max_episode_steps"] == 10
    assert [m.out_features for m in model.actor.latent_pi if isinstance(m, torch.nn.Linear)] == [256, 256]


def test_resume_from_a_checkpoint_continues_exactly(tiny_run, tmp_path):
    run, _ = tiny_run
    boundary = [p for p in ckpt.checkpoint_dirs(run)
                if not ckpt.read_state(p)["mid_episode"] and 0 < ckpt.read_state(p)["model"]["num_timesteps"] < 120]
    assert boundary, "no checkpoint at an episode boundary"
    start = boundary[-1]
    copy = tmp_path / "tiny"
    shutil.copytree(run, copy)
    for later in ckpt.checkpoint_dirs(copy):
        if later.name > start.name:
            shutil.rmtree(later)
    (copy / "model.zip").unlink()
    train_low(TINY, copy, resume=True, progress=False)
    a, b = _params(run / "model.zip"), _params(copy / "model.zip")
    assert all(torch.equal(a[k], b[k]) for k in a)
    before = pd.read_csv(run / "metrics.csv")[["env_steps", "success_rate", "return"]]
    after = pd.read_csv(copy / "metrics.csv")[["env_steps", "success_rate", "return"]]
    pd.testing.assert_frame_equal(before, after)


def test_metrics_log_keeps_every_value_in_its_column(tmp_path):
    """metrics.csv: a row with its columns in another order, or with new ones, lands in the right
    columns; resuming a run whose rows predate schema 2 renames them (success_rate = settled)."""
    from hingelab.training.run_folder import MetricsLog

    log = MetricsLog(tmp_path / "metrics.csv")
    log.append({"env_steps": 0, "success_rate": 0.1, "settled_success_rate": 0.5, "wall_time_s": 0.0, "offline": 1})
    log.append({"env_steps": 20, "success_rate": 0.2, "settled_success_rate": 0.6, "offline": 1, "wall_time_s": 5.5})
    assert pd.read_csv(tmp_path / "metrics.csv")["wall_time_s"].tolist() == [0.0, 5.5]
    log.truncate_after(20)
    log.append({"env_steps": 40, "success_rate": 0.7, "last_step_success_rate": 0.3, "offline": 1,
                "wall_time_s": 7.5, "settled_latent_distance": 0.03})
    table = pd.read_csv(tmp_path / "metrics.csv")
    assert table["success_rate"].tolist() == [0.5, 0.6, 0.7]
    assert table["last_step_success_rate"].tolist() == [0.1, 0.2, 0.3]
    assert table["wall_time_s"].tolist() == [0.0, 5.5, 7.5] and "settled_success_rate" not in table
    assert table["settled_latent_distance"].isna().tolist() == [True, True, False]


def test_resume_keeps_the_config_and_refuses_misuse(tiny_run, tmp_path):
    run, _ = tiny_run
    with pytest.raises(ConfigError, match="already holds a run"):
        train_low(TINY, run, progress=False)
    with pytest.raises(ConfigError, match="does not exist"):
        train_low(TINY, tmp_path / "nothing", resume=True, progress=False)
    with pytest.raises(ConfigError, match="needs datasets"):
        replace(TINY, offline_updates=10)


def test_prefill_from_the_runs_dataset_and_offline_training(tiny_run, tmp_path):
    run, _ = tiny_run
    config = replace(TINY, from_datasets=(str(run / "dataset"),), offline_updates=40, eval_every=20)
    summary = train_low(config, tmp_path / "offline", progress=False)
    prefill = summary["prefill"]
    n_transitions = int(Dataset(run / "dataset").index["length"].sum())  # length counts steps (schema 2)
    assert prefill["transitions"] == n_transitions and prefill["transitions_per_s"] > 0
    metrics = pd.read_csv(tmp_path / "offline" / "metrics.csv")
    assert list(metrics["env_steps"]) == [0, 20, 40]  # offline runs: x = updates
    assert summary["updates"] == 40


def test_prefill_matches_per_transition_add_and_feeds_her(tiny_run):
    from stable_baselines3 import SAC, HerReplayBuffer
    from stable_baselines3.common.buffers import DictReplayBuffer

    from hingelab.episodes.transitions import fill_replay_buffer
    from hingelab.training.buffer_fill import insert_transitions, read_transitions

    run, _ = tiny_run
    transitions, episodes = read_transitions([run / "dataset"])
    model = SAC.load(run / "model.zip")
    slow = DictReplayBuffer(1000, model.observation_space, model.action_space, n_envs=1)
    fast = DictReplayBuffer(1000, model.observation_space, model.action_space, n_envs=1)
    fill_replay_buffer(slow, transitions)
    insert_transitions(fast, transitions)
    assert fast.pos == slow.pos == len(transitions)
    for key in fast.observations:
        np.testing.assert_array_equal(fast.observations[key], slow.observations[key])
        np.testing.assert_array_equal(fast.next_observations[key], slow.next_observations[key])
    np.testing.assert_array_equal(fast.rewards, slow.rewards)
    np.testing.assert_array_equal(fast.dones, slow.dones)
    np.testing.assert_array_equal(fast.timeouts, slow.timeouts)
    # HER: whole episodes per env slot, relabelled samples come out
    from stable_baselines3.common.vec_env import DummyVecEnv

    from hingelab.rollouts.low_level import make_eval_env

    env = DummyVecEnv([lambda: make_eval_env({"max_episode_steps": 10}),
                       lambda: make_eval_env({"max_episode_steps": 10})])
    her = HerReplayBuffer(1000, model.observation_space, model.action_space, env=env, n_envs=2, copy_info_dict=True)
    added = insert_transitions(her, transitions)
    assert added == len(transitions)
    assert her.ep_length.max() <= 10 and (her.ep_length > 0).sum() == len(transitions)
    batch = her.sample(32)
    assert batch.rewards.shape == (32, 1) and np.isfinite(batch.rewards.numpy()).all()
    env.close()


def test_prefill_refuses_another_tasks_data(tiny_run):
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from hingelab.training.buffer_fill import insert_transitions, read_transitions

    run, _ = tiny_run
    transitions, _ = read_transitions([run / "dataset"])
    flat = ReplayBuffer(100, spaces.Box(-1, 1, (14,)), spaces.Box(-1, 1, (5,)))
    with pytest.raises(ConfigError, match="Dict|observations"):
        insert_transitions(flat, transitions)
    with pytest.raises(ConfigError, match="does not exist"):
        read_transitions([run / "no_such_dataset"])


@pytest.mark.slow
def test_parallel_envs_give_the_same_rollouts_as_in_process(tmp_path):
    """Slow (two runs, one with two spawned env processes). By default ``test_vec_env.py::
    test_steps_resets_and_attributes_match_dummy_vec_env`` checks the env processes (PinnedVecEnv) step,
    reset and answer attributes as in-process envs do, and ``test_overlap.py::
    test_overlap_is_recorded_resumed_and_resumes_exactly`` trains ``train low`` on a spawned env process
    (its seeded episodes, checkpoints and an exact resume)."""
    config = replace(TINY, steps=40, n_envs=2, learning_starts=20, eval_every=1000, checkpoint_every=1000,
                     eval_goals_per_region=1, record=False)
    train_low(replace(config, subprocess_envs=True), tmp_path / "subprocess", progress=False)
    train_low(replace(config, subprocess_envs=False), tmp_path / "in_process2", progress=False)
    buffers = [np.load(ckpt.latest_checkpoint(tmp_path / name) / ckpt.BUFFER_FILE)
               for name in ("subprocess", "in_process2")]
    assert any(key.startswith("observations/") for key in buffers[0].files)
    for key in buffers[0].files:
        np.testing.assert_array_equal(buffers[0][key], buffers[1][key])


def test_eval_low_cli_writes_a_dataset_and_a_region_table(tiny_run, tmp_path):
    from hingelab.cli.main import main

    run, _ = tiny_run
    out = tmp_path / "eval"
    assert main(["eval", "low", str(run / "model.zip"), "--episodes", "3", "--out", str(out), "--no-progress"]) == 0
    regions = pd.read_csv(out / "regions.csv")
    assert list(regions["goal_region"]) == ["closed", "middle", "open", "all"]
    assert regions.set_index("goal_region").loc["all", "episodes"] == 3
    assert len(Dataset(out)) == 3
    assert (out / "report.md").read_text().count("|") > 20
    assert main(["eval", "low", str(tmp_path / "missing.zip"), "--episodes", "1", "--out",
                 str(tmp_path / "e2")]) == 1


def test_eval_low_references_hold_still_and_synergy(tmp_path, capsys):
    """The two references behind `hingelab eval low --baseline`: the scripted synergy (latent
    feedback) settles nearer its latent goals than holding still does. (The true hinge it ends at
    can differ from the goal's calibrated opening: the in-hand latent's offset varies by episode,
    which ``tip_gap_error_mm`` reports.) One verdict: the region table counts the episodes' rows,
    the rows are the episodes the dataset records, and `hingelab report` of the dataset counts the
    same successes."""
    from scipy.stats import binomtest

    from hingelab.cli.main import main

    distances, settled = {}, {}
    for baseline in ("hold-still", "synergy"):
        out = tmp_path / baseline
        assert main(["eval", "low", "--baseline", baseline, "--episodes", "3", "--out", str(out),
                     "--no-progress"]) == 0
        printed = capsys.readouterr().out.strip().splitlines()[-1]
        episodes = pd.read_csv(out / "episodes.csv").sort_values("goal_opening_rad")
        assert {"success", "last_step_success", "settled_latent_distance", "tip_gap_error_mm"} <= set(episodes.columns)
        assert "settled_success" not in episodes.columns
        assert (episodes["tip_gap_error_mm"] >= 0).all() and len(Dataset(out)) == 3
        # the verdict is the settled distance under the threshold; the secondary one the last frame's
        threshold = float((out / "report.md").read_text().split("success threshold ")[1].split(" ")[0])
        assert (episodes["success"] == (episodes["settled_latent_distance"] < threshold)).all()
        assert (episodes["last_step_success"] == (episodes["final_latent_distance"] < threshold)).all()
        regions = pd.read_csv(out / "regions.csv").set_index("goal_region")
        for region, part in [("all", episodes), *episodes.groupby("region")]:
            row = regions.loc[region]
            k, n = int(part["success"].sum()), len(part)
            assert (row["episodes"], row["successes"]) == (n, k)
            assert row["success_rate"] == pytest.approx(k / n)
            interval = binomtest(k, n).proportion_ci(method="wilson")
            assert (row["ci_low"], row["ci_high"]) == pytest.approx((interval.low, interval.high), abs=1e-9)
            assert row["last_step_successes"] == int(part["last_step_success"].sum())
        # the dataset records the same verdicts, episode by episode
        index = Dataset(out).index.set_index("seed").loc[episodes["seed"]]
        assert index["success"].tolist() == episodes["success"].tolist()
        assert index["last_step_success"].tolist() == episodes["last_step_success"].tolist()
        assert (index["success_verdict"] == "settled_0.5s").all()
        # and the report of the dataset counts what eval printed
        assert f"success (settled over the last 10 steps, the episodes' recorded verdict) " \
               f"{int(episodes['success'].sum())}/3 = " in printed
        assert main(["report", str(out), "--out", str(tmp_path / f"report-{baseline}")]) == 0
        by_dataset = pd.read_csv(tmp_path / f"report-{baseline}" / "success_by_dataset.csv")
        assert by_dataset["successes"].tolist() == [regions.loc["all", "successes"]]
        assert by_dataset["verdict"].tolist() == ["settled over the last 0.5 s (ToolShape-v0)"]
        markdown = (tmp_path / f"report-{baseline}" / "report.md").read_text()
        assert "What success counts: " in markdown and "settled over the last 0.5 s (ToolShape-v0)" in markdown
        distances[baseline] = episodes["settled_latent_distance"].mean()
        settled[baseline] = int(episodes["success"].sum())
    assert distances["synergy"] < distances["hold-still"] and settled["synergy"] >= 1, (distances, settled)
    from hingelab.analysis.low_level_summary import write_summary

    table = write_summary(tmp_path / "summary", [tmp_path / "hold-still", tmp_path / "synergy"])
    assert list(table["policy"]) == ["hold-still", "synergy"] and (table["episodes"] == 3).all()
    assert table.loc[1, "success"].startswith(f"{settled['synergy'] / 3:.2f} [")
    assert (tmp_path / "summary.md").read_text().count("|") > 20
    assert main(["eval", "low", "x.zip", "--baseline", "synergy", "--out", str(tmp_path / "both")]) == 1


def test_prefill_relabels_rewards_with_the_runs_own_reward(tiny_run):
    """Recorded with the effort term, the same transitions train a --no-effort run on the goal term alone."""
    import gymnasium as gym

    from hingelab.training.buffer_fill import read_transitions, relabel_rewards

    run, _ = tiny_run
    recorded, _ = read_transitions([run / "dataset"])
    with_effort = gym.make("hingelab/ToolShape-v0", use_effort=True).unwrapped
    without = gym.make("hingelab/ToolShape-v0", use_effort=False).unwrapped
    same = relabel_rewards(read_transitions([run / "dataset"])[0], with_effort)
    np.testing.assert_allclose(same.rewards, recorded.rewards, rtol=1e-5, atol=1e-6)
    goal_only = relabel_rewards(read_transitions([run / "dataset"])[0], without)
    distance = np.linalg.norm(recorded.next_observations["achieved_goal"] - recorded.observations["desired_goal"],
                              axis=1)
    np.testing.assert_allclose(goal_only.rewards, np.exp(-without.reward_config.c1 * distance), rtol=1e-5)
    assert (goal_only.rewards >= recorded.rewards - 1e-6).all()  # the effort term only ever subtracts
    # another effort weight: the tool-motion part scales with c2, from the recorded unweighted motion
    heavy = gym.make("hingelab/ToolShape-v0", effort_weight=200.0).unwrapped
    stiff = relabel_rewards(read_transitions([run / "dataset"])[0], heavy)
    motion, speed = recorded.infos["tool_motion_m"], recorded.infos["finger_speed"]
    assert motion.max() > 0
    np.testing.assert_allclose(stiff.rewards, goal_only.rewards - 200.0 * motion - heavy.reward_config.c3 * speed,
                               rtol=1e-5, atol=1e-6)
    # a dataset that records only the weighted effort cannot be reweighted
    old = read_transitions([run / "dataset"])[0]
    del old.infos["tool_motion_m"], old.infos["finger_speed"]
    with pytest.raises(DatasetError, match="c2 200"):
        relabel_rewards(old, heavy)
    np.testing.assert_allclose(relabel_rewards(old, with_effort).rewards, recorded.rewards, rtol=1e-5, atol=1e-6)


def test_drift_weight_charges_the_tools_true_drift_beyond_5mm(tiny_run):
    """--drift-weight: the env's reward and compute_reward agree, recorded transitions relabel
    from their recorded drift, and transitions without it are refused for such a run."""
    import gymnasium as gym

    from hingelab.training.buffer_fill import read_transitions, relabel_rewards

    env = gym.make("hingelab/ToolShape-v0", drift_weight=400.0, goal_sampling="reachable").unwrapped
    _, info = env.reset(seed=3)
    # the reset's terms are the steps' (0 each): a recorded field has a row for every message
    assert info["reward_terms"] == {"goal": 0.0, "effort_tool": 0.0, "effort_fingers": 0.0, "drift": 0.0}
    drift_terms = []
    for k in range(30):
        # squeeze and release hard: the tool moves in the hand
        _, reward, _, _, info = env.step(np.full(9, 1.0 if k % 10 < 5 else -1.0))
        expected = -400.0 * max(0.0, info["tool_drift_m"] - 0.005)
        assert info["reward_terms"]["drift"] == pytest.approx(expected)
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        recomputed = env.compute_reward(env.sample.z_smoothed[0][None], env.goal[None], [info])[0]
        assert recomputed == pytest.approx(reward, rel=1e-6, abs=1e-9)
        drift_terms.append(expected)
    assert min(drift_terms) < 0  # the hard squeezes moved the tool more than 5 mm
    assert gym.make("hingelab/ToolShape-v0").unwrapped.reward_config.c4 == 0  # off by default: the paper's reward

    run, _ = tiny_run
    plain = gym.make("hingelab/ToolShape-v0").unwrapped
    base = relabel_rewards(read_transitions([run / "dataset"])[0], plain)
    drifting = relabel_rewards(read_transitions([run / "dataset"])[0], env)
    drift = read_transitions([run / "dataset"])[0].infos["tool_drift_m"]
    np.testing.assert_allclose(drifting.rewards, base.rewards - 400.0 * np.maximum(0, drift - 0.005),
                               rtol=1e-5, atol=1e-6)
    old = read_transitions([run / "dataset"])[0]
    del old.infos["tool_drift_m"]
    with pytest.raises(DatasetError, match="tool_drift_m"):
        relabel_rewards(old, env)
    with pytest.raises(ConfigError, match="drift_weight"):
        gym.make("hingelab/ToolShape-v0", drift_weight=-1.0)
    with pytest.raises(ConfigError, match="drift"):
        replace(TINY, use_effort=False, drift_weight=60.0)


def test_a_goal_band_is_part_of_the_config_and_the_env():
    """--goal-openings LOW:HIGH (an expert's goals): saved as a tuple, given to the env, checked."""
    from hingelab.learners.sac.low_level_config import LowLevelTrainConfig

    config = replace(TINY, goal_openings=[0.0, 0.1])
    assert config.goal_openings == (0.0, 0.1) and config.env_arguments()["goal_openings"] == (0.0, 0.1)
    assert LowLevelTrainConfig.from_dict(config.to_dict()) == config
    assert "goal_openings" not in TINY.env_arguments()  # runs without a band make the env as before
    for bad in ((0.1, 0.0), (0.0,)):
        with pytest.raises(ConfigError, match="goal-openings"):
            replace(TINY, goal_openings=bad)
    with pytest.raises(ConfigError, match="goal-openings"):
        replace(TINY, goal_openings=(0.0, 0.1), goal_sampling="normal")


def test_learning_from_demonstrations_pretrains_and_anchors_the_actor(tiny_run, tmp_path):
    """--bc-pretrain fits the actor to the --from episodes' actions; --bc-weight keeps a
    Q-filtered BC term in the actor loss (DemoSAC owns it); the checkpoint does not carry the
    demonstrations."""
    from hingelab.learners.sac.demo_sac import Demonstrations, DemoSAC
    from hingelab.training.buffer_fill import read_transitions

    run, _ = tiny_run
    transitions, _ = read_transitions([run / "dataset"])
    model = DemoSAC.load(run / "model.zip", device="cpu", bc_weight=1.0)
    # the tiny run's own actions are random; a demonstrator acts as a function of the state
    transitions.actions = np.tanh(3 * transitions.observations["observation"][:, :9]).astype(np.float32)
    model.set_demonstrations(Demonstrations.from_transitions(transitions))
    losses = model.pretrain_actor(updates=300, batch_size=32)
    assert losses[-1] < 0.5 * losses[0], losses
    term = model.bc_loss(64)
    model.q_filter = False
    unfiltered = model.bc_loss(64)
    assert term.requires_grad and 0 <= float(term) <= float(unfiltered) + 9 * 4
    assert model._extra_actor_loss(64) is not None
    model.bc_weight = 0.0
    assert model._extra_actor_loss(64) is None  # weight 0: plain SAC
    config = replace(TINY, steps=60, from_datasets=(str(run / "dataset"),), demo_bc_weight=1.0,
                     bc_pretrain_updates=50, algorithm="fast_sac", eval_every=60, checkpoint_every=60)
    summary = train_low(config, tmp_path / "bc", progress=False)
    assert summary["env_steps"] == 60
    saved = DemoSAC.load(tmp_path / "bc" / "model.zip", device="cpu")
    assert saved.demonstrations is None and saved.bc_weight == 1.0
    (tmp_path / "bc" / "run.json").write_text(json.dumps({"name": "relabelled"}))  # a new curve label
    train_low(replace(config, steps=90), tmp_path / "bc", resume=True, progress=False)  # demos re-read on resume
    assert Dataset(tmp_path / "bc" / "dataset").card.name == "bc-rollouts"  # the card keeps its name
    with pytest.raises(ConfigError, match="needs them"):
        replace(TINY, demo_bc_weight=1.0)
    with pytest.raises(ConfigError, match="fast_sac"):
        replace(config, algorithm="sac")


def test_policy_records_its_encoder_and_is_refused_beside_another(tiny_run, tmp_path):
    """A trained policy knows whose latents it learned; beside another encoder it is refused."""
    from hingelab.envs.low_level import PolicyLowLevel
    from hingelab.perception.encoder import PointNetVAE, ToolEncoder, load_encoder, shipped_encoder_fingerprint

    run, _ = tiny_run
    from stable_baselines3 import SAC

    assert SAC.load(run / "model.zip").hingelab_provenance["encoder_fingerprint"] == shipped_encoder_fingerprint()
    PolicyLowLevel(run / "model.zip")  # the shipped encoder: accepted
    shipped = load_encoder()
    torch.manual_seed(1)
    other = ToolEncoder(PointNetVAE(shipped.model.config), shipped.calibration)
    assert other.fingerprint != shipped.fingerprint
    with pytest.raises(ConfigError, match="another tool encoder"):
        PolicyLowLevel(run / "model.zip", encoder=other)


def test_init_from_starts_a_new_run_from_a_trained_policy(tiny_run, tmp_path):
    """--init-from: the new run starts with the policy's actor, critics and entropy coefficient
    (its own config, buffer and rollouts); networks of another shape are a one-line error."""
    from stable_baselines3 import SAC

    run, _ = tiny_run
    source = SAC.load(run / "model.zip", device="cpu")
    start = replace(TINY, steps=0, init_from=str(run), eval_every=1000, checkpoint_every=1000)
    train_low(start, tmp_path / "start", progress=False)
    started = SAC.load(tmp_path / "start" / "model.zip", device="cpu")
    for name, tensor in source.policy.state_dict().items():
        assert torch.equal(tensor, started.policy.state_dict()[name]), name
    assert torch.equal(source.log_ent_coef, started.log_ent_coef)
    assert json.loads((tmp_path / "start" / "config.json").read_text())["config"]["init_from"] == str(run)
    moved = train_low(replace(start, steps=60), tmp_path / "tuned", progress=False)
    assert moved["env_steps"] == 60 and moved["updates"] > 0
    tuned = SAC.load(tmp_path / "tuned" / "model.zip", device="cpu").policy.state_dict()
    assert any(not torch.equal(t, tuned[k]) for k, t in source.policy.state_dict().items())
    with pytest.raises(ConfigError, match="does not fit this run's networks"):
        train_low(replace(start, net_arch=(32, 32)), tmp_path / "small", progress=False)
    with pytest.raises(ConfigError, match="does not exist"):
        train_low(replace(start, init_from=str(tmp_path / "nowhere.zip")), tmp_path / "none", progress=False)
    assert not (tmp_path / "none").exists()  # nothing to clear away before running it again


def test_resume_on_the_command_line_keeps_the_runs_settings(tiny_run, tmp_path, capsys):
    """``--resume`` continues the run as its config.json says: no default --steps extends it, and a
    given flag that differs from the run's (other than --steps and --on-corrupt) is refused."""
    from hingelab.cli.main import main

    run, _ = tiny_run
    copy = tmp_path / "tiny"
    shutil.copytree(run, copy)
    assert main(["train", "low", "--out", str(copy), "--resume", "--seed", "3", "--no-progress"]) == 1
    error = capsys.readouterr().err
    assert "--seed (seed=3, the run's 0)" in error and "--steps and --on-corrupt" in error
    assert main(["train", "low", "--out", str(copy), "--resume", "--on-corrupt", "skip", "--no-progress"]) == 0
    steps = pd.read_csv(copy / "metrics.csv")["env_steps"]
    assert steps.max() == TINY.steps  # not the default --steps
    assert steps.is_unique  # a resume with nothing left to run does not evaluate its end again
    assert ckpt.read_state(ckpt.latest_checkpoint(copy))["model"]["num_timesteps"] == TINY.steps
