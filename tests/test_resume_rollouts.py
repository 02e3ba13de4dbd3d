"""A training run killed and resumed writes each rollout once: its ``RUNDIR/dataset`` ends episode for
episode as an uninterrupted run's, whether the kill came before, during or after a checkpoint.

The kill is a ``KeyboardInterrupt`` raised inside the run at a chosen env step (in-process, so it is
deterministic): the run stops there as a killed process would, its finished episodes on disk and the
one under way a ``.partial`` file; ``--resume`` continues from the last complete checkpoint."""

from __future__ import annotations

import shutil

import pandas as pd
import pytest
from stable_baselines3.common.callbacks import BaseCallback

from hingelab.episodes.dataset import Dataset
from hingelab.learners.sac import run as sac_run
from hingelab.learners.sac.low_level import train_low
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
from hingelab.training import checkpoints as ckpt
from hingelab.training import resume_state
from hingelab.training.run_folder import covered_episodes

# 10-step episodes, checkpoints every 30 env steps, no evaluation but the first and the last
TINY = LowLevelTrainConfig(
    steps=80, n_envs=1, max_episode_steps=10, learning_starts=30, batch_size=16, buffer_size=2000,
    eval_every=10_000, eval_goals_per_region=1, checkpoint_every=30, keep_checkpoints=10, algorithm="sac",
    net_arch=(16,),
)
COLUMNS = ["seed", "length", "return", "success"]


def _rollouts(run) -> pd.DataFrame:
    index = Dataset(run / "dataset").index
    return index[COLUMNS].sort_values("seed", ignore_index=True)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    run = tmp_path_factory.mktemp("runs") / "whole"
    train_low(TINY, run, progress=False)
    return run


class _KillAt(BaseCallback):
    """Stops the run (as a kill would) once it has taken ``step`` env steps."""

    def __init__(self, step: int):
        super().__init__(verbose=0)
        self.step = step

    def _on_step(self) -> bool:
        if self.model.num_timesteps >= self.step:
            raise KeyboardInterrupt(f"killed at env step {self.model.num_timesteps}")
        return True


def _kill_between(monkeypatch, step: int) -> None:
    original = sac_run.run_callbacks

    def with_kill(*args, **kwargs):
        callbacks = original(*args, **kwargs)
        callbacks.callbacks.append(_KillAt(step))
        return callbacks

    monkeypatch.setattr(sac_run, "run_callbacks", with_kill)


def _kill_while_saving(monkeypatch, step: int) -> None:
    original = resume_state.save_buffer

    def save_then_die(buffer, path):
        if path.parent.name.endswith(f"step_{step:012d}"):  # the checkpoint's temporary folder
            path.write_bytes(b"half a buffer")
            raise KeyboardInterrupt(f"killed while writing {path}")
        return original(buffer, path)

    monkeypatch.setattr(resume_state, "save_buffer", save_then_die)


def _kill_after_saving(monkeypatch, step: int) -> None:
    original = sac_run.SACRun.checkpoint_now

    def save_then_die(self, mid_episode):
        path = original(self, mid_episode)
        if self.model.num_timesteps == step:
            raise KeyboardInterrupt(f"killed just after writing {path}")
        return path

    monkeypatch.setattr(sac_run.SACRun, "checkpoint_now", save_then_die)


@pytest.mark.parametrize("when, resumes_from", [
    ("before", 30),  # at env step 59, one step before the checkpoint of 60: episodes 40 and 50 came after 30's
    ("during", 30),  # while checkpoint 60 was being written (left half-written): 40, 50 and 60 came after 30's
    ("after", 60),  # right after checkpoint 60 was complete: nothing came after it
])
def test_a_killed_and_resumed_run_writes_each_rollout_once(uninterrupted, tmp_path, monkeypatch, when, resumes_from):
    run = tmp_path / "killed"
    with monkeypatch.context() as patch:
        {"before": lambda: _kill_between(patch, 59), "during": lambda: _kill_while_saving(patch, 60),
         "after": lambda: _kill_after_saving(patch, 60)}[when]()
        with pytest.raises(KeyboardInterrupt):
            train_low(TINY, run, progress=False)
    assert ckpt.latest_checkpoint(run).name == f"step_{resumes_from:012d}"
    state = ckpt.read_state(ckpt.latest_checkpoint(run))
    assert state["finished_episodes"] == [resumes_from // TINY.max_episode_steps]  # what the checkpoint covers

    train_low(TINY, run, resume=True, progress=False)
    resumed, whole = _rollouts(run), _rollouts(uninterrupted)
    assert resumed["seed"].is_unique
    pd.testing.assert_frame_equal(resumed, whole)
    assert not list((run / "dataset" / "episodes").glob("*.partial"))


def test_a_resume_from_an_earlier_checkpoint_drops_every_later_rollout(uninterrupted, tmp_path):
    """Resuming from the first checkpoint of a finished run (the later ones deleted): the rollouts after it
    are replayed once, not kept beside their replays."""
    run = tmp_path / "copy"
    shutil.copytree(uninterrupted, run)
    first = ckpt.checkpoint_dirs(run)[0]
    for later in ckpt.checkpoint_dirs(run)[1:]:
        shutil.rmtree(later)
    (run / "model.zip").unlink()
    assert first.name == "step_000000000030"
    train_low(TINY, run, resume=True, progress=False)
    pd.testing.assert_frame_equal(_rollouts(run), _rollouts(uninterrupted))


def test_what_a_checkpoint_covers_and_what_an_older_ones_counts_say():
    assert covered_episodes({"finished_episodes": [3, 2], "episode_counts": [3, 3], "mid_episode": True}) == [3, 2]
    # an older hingelab's checkpoint: at an episode boundary its counts are the finished episodes ...
    assert covered_episodes({"episode_counts": [3, 4], "mid_episode": False}) == [3, 4]
    # ... mid-episode they count each env's episode under way, which had not finished
    assert covered_episodes({"episode_counts": [3, 4], "mid_episode": True}) == [2, 3]


def test_a_resume_keeps_one_of_a_rollout_an_older_resume_recorded_twice(uninterrupted, tmp_path):
    run = tmp_path / "copy"
    shutil.copytree(uninterrupted, run)
    episodes = run / "dataset" / "episodes"
    first = sorted(episodes.glob("*.mcap"))[0]
    twice = episodes / first.name.replace("low_level_training-", "low_level_training-9")  # recorded later
    shutil.copy(first, twice)
    assert len(Dataset(run / "dataset").index) == len(_rollouts(uninterrupted)) + 1
    train_low(TINY, run, resume=True, progress=False)  # nothing left to train: only the set-up runs
    pd.testing.assert_frame_equal(_rollouts(run), _rollouts(uninterrupted))
    assert twice.exists() and not first.exists()  # the later one, the replay the checkpoint learned from
