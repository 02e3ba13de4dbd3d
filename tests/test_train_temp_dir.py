"""A training run leaves nothing in the temp directory: stable-baselines3's logger gets no folder (its
``configure()`` would make an empty ``SB3-<time>`` folder there on every run)."""

import tempfile

from hingelab.learners.sac.low_level import train_low
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig


def test_train_low_leaves_no_sb3_folder_in_the_temp_dir(tmp_path, monkeypatch):
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    config = LowLevelTrainConfig(steps=20, n_envs=1, subprocess_envs=False, max_episode_steps=10, learning_starts=10,
                                 batch_size=8, buffer_size=200, eval_every=20, eval_goals_per_region=1,
                                 checkpoint_every=20, net_arch=(16,))
    train_low(config, tmp_path / "run", progress=False)
    assert [p.name for p in temp.iterdir() if p.name.startswith("SB3-")] == []
