"""ToolPick-v0's ``observe_extent``: the object's bounding box in the observation, through a
train-high run (prior, pre-fill, evaluation) and eval high of its checkpoint."""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from hingelab.envs import TOOL_PICK_FLAT_ID, TOOL_PICK_ID


@pytest.mark.parametrize("object,size,extent_mm", [
    ("sphere", 0.02, (20, 20, 20)), ("cube", 0.015, (15, 15, 15)),
    ("tetrahedron", 0.02, (20 * np.sqrt(3) / 2, 20, 20 * np.sqrt(2 / 3)))])
def test_extent_is_the_bounding_box(object, size, extent_mm):
    env = gym.make(TOOL_PICK_ID, object=object, size=size, observe_extent=True, randomize=False)
    obs, _ = env.reset(seed=2)
    pick = env.unwrapped
    assert obs.shape == (17,) and env.observation_space.shape == (17,)
    assert 1000 * pick.observed_object_extent() == pytest.approx(extent_mm, abs=0.3)
    assert np.abs(obs[14:] - pick.observed_object_extent()).max() < 0.01  # 2 mm noise
    assert gym.make(TOOL_PICK_ID, randomize=False).observation_space.shape == (14,)
    assert gym.make(TOOL_PICK_FLAT_ID, observe_extent=True, randomize=False).observation_space.shape == (35,)


def test_a_run_with_the_extent_trains_and_evaluates(tmp_path, capsys):
    from hingelab.cli.main import main
    from hingelab.learners.sac.high_level import train_high
    from hingelab.policies.high_level import load_high_level_checkpoint
    from test_train_high import TINY

    config = replace(TINY, steps=60, eval_every=60, checkpoint_every=60, prior_episodes=2, max_episode_steps=20,
                     bc_pretrain_updates=5, demo_offline_updates=0, env_kwargs={"observe_extent": True})
    summary = train_high(config, tmp_path / "run", progress=False)
    assert summary["prior"]["transitions"] > 0
    model = load_high_level_checkpoint(tmp_path / "run" / "model.zip")
    assert model.observation_space.shape == (17,)
    assert model.hingelab_provenance["env_kwargs"]["observe_extent"] is True
    out = tmp_path / "eval"
    assert main(["eval", "high", str(tmp_path / "run" / "model.zip"), "--low-level", "privileged",
                 "--episodes", "1", "--out", str(out), "--no-progress"]) == 0
    assert (out / "table.csv").exists()


def test_demos_of_the_other_observation_get_a_one_line_error(tmp_path):
    from hingelab.episodes.errors import DatasetError
    from hingelab.policies.baselines import ScriptedPolicy
    from hingelab.rollouts.high_level import evaluate, make_eval_env
    from hingelab.training.high_level_demos import high_level_transitions

    root = tmp_path / "demos"
    from hingelab.episodes import create_dataset

    create_dataset(root, name="d", source="heuristic", seed=0, config={"policy": "scripted"})
    from hingelab.envs.recording import RecordingWrapper

    env = RecordingWrapper(make_eval_env("sphere", 0.02, "privileged", max_episode_steps=10), root, source="heuristic",
                           object_name="sphere", action_level="high")
    evaluate(ScriptedPolicy(), env, 1, 0)
    env.close()
    assert high_level_transitions([root], actions="recorded").observations.shape[1] == 14
    with pytest.raises(DatasetError, match="observe_extent"):
        high_level_transitions([root], actions="recorded", observation_dim=17)
