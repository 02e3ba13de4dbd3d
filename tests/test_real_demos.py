"""Real-rig episodes as a training source: a rig bag recorded on the simulator (heuristic trials on
ToolPick-v0: its arm joints, object pose, camera clouds, actions and success events) imported with
``hingelab datasets import-ros2``, relabelled from perception and the arm's kinematics, and compared
with the rewards the env gave the same trials from privileged state; ``train high --from`` on it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hingelab.cli.main import main
from hingelab.envs.rewards import HighLevelRewardConfig
from hingelab.episodes import read_episode
from hingelab.episodes.dataset import Dataset
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag
from hingelab.ros2.sim_rig_bag import SimRigBagSpec, write_sim_rig_bag
from hingelab.sim.arm_kinematics import default_kinematics
from hingelab.training.high_level_demos import high_level_transitions
from hingelab.training.real_demos import RealEpisodeError, real_episode_transitions

# Perception is not privileged truth: the grip point rebuilt from the registered pose and the latent's
# opening lies within a few mm of the sim's (measured: 2-3 mm at most), and the tool-object term
# exp(-20 d) moves by at most 20 x that. The object-target term uses the same object pose as the env.
REWARD_TOLERANCE = 0.05
MEAN_REWARD_TOLERANCE = 0.015


@pytest.fixture(scope="module")
def sim_rig(tmp_path_factory):
    """Two heuristic trials recorded as a rig bag and imported; the env's truth per trial, in the order the
    dataset yields the episodes."""
    root = tmp_path_factory.mktemp("sim_rig")
    info = write_sim_rig_bag(root / "bag", SimRigBagSpec(episodes=2, seed=3))
    assert main(["datasets", "import-ros2", str(root / "bag"), "--out", str(root / "real"), "--no-progress"]) == 0
    order = [int(ep.metadata["ros2_trial_index"]) for ep in Dataset(root / "real").iter_episodes(topics=["/step"])]
    return root, [info["trials"][i] for i in order]


def _per_episode(tr, k):
    return tr.episode_index == k


def test_relabelled_rewards_are_the_envs_within_perceptions_error(sim_rig):
    root, trials = sim_rig
    tr = high_level_transitions([root / "real"])
    assert np.isfinite(tr.rewards).all() and np.isfinite(tr.observations).all()
    for k, truth in enumerate(trials):
        rows = _per_episode(tr, k)
        assert rows.sum() == len(truth["rewards"])  # one transition per env step, up to the success
        error = np.abs(tr.rewards[rows] - truth["rewards"])
        assert error.max() < REWARD_TOLERANCE and error.mean() < MEAN_REWARD_TOLERANCE, (error.max(), error.mean())
        # the object-target term: the same object pose, through TF and the arm's kinematics and back
        d_target = tr.infos["object_target_distance"][rows]
        np.testing.assert_allclose(np.exp(-20.0 * d_target), truth["terms"]["object_target"], atol=1e-9)
        assert truth["success"] and tr.terminated[rows][-1] and not tr.terminated[rows][:-1].any()
        assert tr.rewards[rows][-1] > 10.0 and (tr.rewards[rows][:-1] < 10.0).all()  # c_h1 on the success step
        assert not tr.infos["table_collision"][rows].any() and not truth["table_collision"].any()


def test_the_reward_is_the_envs_formula_with_the_target_5cm_above_the_start(sim_rig):
    root, trials = sim_rig
    config = HighLevelRewardConfig(c_h1=50.0, c_h2=10.0, c_h3=2.0, c_h4=30.0, c_h5=3.0)
    tr = high_level_transitions([root / "real"], config)
    d_tool, d_target = tr.infos["tool_object_distance"], tr.infos["object_target_distance"]
    penalty = (d_tool > config.far) | (d_target > config.far) | (tr.infos["table_collision"] > 0.5)
    expected = ((config.c_h1 + config.absorbing_bonus) * tr.infos["is_success"] + np.exp(-config.c_h2 * d_tool)
                + config.c_h3 * np.exp(-config.c_h4 * d_target) - config.c_h5 * penalty)
    np.testing.assert_allclose(tr.rewards, expected, rtol=1e-12, atol=1e-12)
    # the observation's target (NaN as imported) is the env's: 5 cm above the object's start, in hand_base
    episodes = list(Dataset(root / "real").iter_episodes(topics=["/step"]))
    kin = default_kinematics()
    for k, (episode, truth) in enumerate(zip(episodes, trials)):
        step = episode.topics["/step"]
        assert np.isnan(step["observation"][:, 11:14]).all()
        arm = np.column_stack([step[f"info.arm_joint_{j}"] for j in range(1, 7)])[:_per_episode(tr, k).sum()]
        rot, pos = kin.hand_poses(arm)
        target_world = np.einsum("tij,tj->ti", rot, tr.observations[_per_episode(tr, k), 11:14]) + pos
        np.testing.assert_allclose(target_world, np.broadcast_to(truth["target_world"], target_world.shape),
                                   atol=1e-9)
        start = truth["states"][0]["object"]
        np.testing.assert_allclose(truth["target_world"], start + [0.0, 0.0, 0.05], atol=1e-12)


def test_actions_recorded_where_the_rig_logged_them_else_reached(sim_rig):
    root, trials = sim_rig
    recorded = high_level_transitions([root / "real"], actions="recorded")
    reached = high_level_transitions([root / "real"], actions="reached")
    assert recorded.infos["demo_action_recorded"].all() and not reached.infos["demo_action_recorded"].any()
    for k, truth in enumerate(trials):
        rows = _per_episode(recorded, k)
        np.testing.assert_allclose(recorded.actions[rows], truth["actions"], atol=1e-12)
        # reached: the latent at the next step / 3, the hand velocity measured by kinematics / 0.08
        next_z = recorded.next_observations[rows, 6:8]
        np.testing.assert_allclose(reached.actions[rows, :2], np.clip(next_z / 3.0, -1, 1), atol=1e-12)
        velocity_error = np.abs(reached.actions[rows, 2:] - truth["actions"][:, 2:])
        assert np.median(velocity_error) < 0.02 and velocity_error.max() <= 2.0  # the servos lag the command


def test_an_episode_without_what_the_reward_needs_is_one_line_naming_the_topic(sim_rig, tmp_path, capsys):
    root, _ = sim_rig
    from hingelab.perception.encoder import load_encoder

    calibration = load_encoder().calibration
    path = Dataset(root / "real").paths()[0]
    episode = read_episode(path)
    del episode.topics["/step"]["info.arm_joint_3"]
    with pytest.raises(RealEpisodeError) as err:
        real_episode_transitions(episode, 0, HighLevelRewardConfig(), calibration)
    assert "\n" not in str(err.value) and str(path) in str(err.value) and "arm_joint_3" in str(err.value)
    assert "/joint_states" in str(err.value)
    episode = read_episode(path)
    arm_1 = episode.topics["/step"]["info.arm_joint_1"].copy()  # the reader's arrays are read-only
    arm_1[5] = np.nan
    episode.topics["/step"]["info.arm_joint_1"] = arm_1
    with pytest.raises(RealEpisodeError, match="NaN at 1 of"):
        real_episode_transitions(episode, 0, HighLevelRewardConfig(), calibration)
    with pytest.raises(RealEpisodeError, match="observe_extent"):
        real_episode_transitions(read_episode(path), 0, HighLevelRewardConfig(), calibration, observation_dim=17)
    # a rig without an object detector: train high refuses in one line naming the topic to record
    write_rig_bag(tmp_path / "no_object", RigBagSpec(trials=[RigTrial()], object_pose=False))
    assert main(["datasets", "import-ros2", str(tmp_path / "no_object"), "--out", str(tmp_path / "blind"),
                 "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["train", "high", "--from", str(tmp_path / "blind"), "--steps", "10", "--out", str(tmp_path / "run"),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hingelab: error: ") and "/object/pose" in err[0]
    assert "ros2 bag record" in err[0] and "/object/position" in err[0]
    # a dataset with some such episodes: they are left out and listed, the others used
    assert main(["datasets", "import-ros2", str(tmp_path / "no_object"), "--out", str(tmp_path / "mixed"),
                 "--no-progress"]) == 0
    write_rig_bag(tmp_path / "with_object", RigBagSpec(trials=[RigTrial(), RigTrial(outcome="failure")]))
    assert main(["datasets", "import-ros2", str(tmp_path / "with_object"), "--out", str(tmp_path / "mixed"),
                 "--no-progress"]) == 0
    skipped = []
    tr = high_level_transitions([tmp_path / "mixed"], skipped=skipped)
    assert len(skipped) == 1 and "/object/position" in skipped[0][1] and len(np.unique(tr.episode_index)) == 2
    assert tr.terminated.sum() == 1 and tr.truncated.sum() == 1  # the success ends one, the failure runs out


TRAIN = ["--steps", "200", "--envs", "1", "--max-episode-steps", "40", "--learning-starts", "40", "--batch-size", "16",
         "--buffer-size", "2000", "--net-arch", "16", "16", "--eval-every", "200", "--eval-episodes", "1",
         "--checkpoint-every", "200", "--bc-pretrain", "20", "--low-level", "privileged", "--no-randomize",
         "--no-progress"]


def test_train_high_from_real_episodes_and_with_simulated_demos(sim_rig, tmp_path, capsys):
    root, trials = sim_rig
    real = root / "real"
    assert main(["train", "high", "--from", str(real), "--out", str(tmp_path / "real_run"), *TRAIN]) == 0
    out = capsys.readouterr().out
    assert "Trained the high-level policy to 200 env steps" in out and f"{real.resolve()} (real, 2 episodes)" in out
    prior = json.loads((tmp_path / "real_run" / "config.json").read_text())["prior"]
    steps = sum(len(t["rewards"]) for t in trials)
    assert prior["sources"] == ["real"] and prior["transitions"] == steps
    (filled,) = prior["filled_from"]
    assert filled["path"] == str(real.resolve()) and filled["source"] == "real" and filled["episodes"] == 2
    assert filled["demo_actions"] == "recorded" and filled["transitions_with_recorded_action"] == steps
    # mixed: simulated heuristic demos and the real episodes in one buffer
    sim = tmp_path / "heuristic"
    assert main(["generate", "heuristic", "--episodes", "1", "--out", str(sim), "--no-progress"]) in (0, None)
    assert main(["train", "high", "--from", str(sim), str(real), "--out", str(tmp_path / "mixed_run"), *TRAIN]) == 0
    prior = json.loads((tmp_path / "mixed_run" / "config.json").read_text())["prior"]
    assert prior["sources"] == ["heuristic", "real"] and prior["episodes"] == 3
    assert [d["source"] for d in prior["filled_from"]] == ["heuristic", "real"]
    assert prior["transitions"] == sum(d["transitions"] for d in prior["filled_from"])
