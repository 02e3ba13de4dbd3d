"""Shared fixtures: scenes are compiled once per session (each compile takes ~50 ms)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session")
def synergy():
    from hingelab.sim.finger_synergy import FingerSynergy

    return FingerSynergy.load()


@pytest.fixture(scope="session")
def random_pick_dataset(tmp_path_factory):
    """A factory of datasets of real ToolPick-v0 episodes (random actions, privileged low level) as
    ``RecordingWrapper`` writes them: clouds, columns, metadata."""
    from hingelab.episodes import create_dataset
    from hingelab.policies.baselines import RandomPolicy
    from hingelab.rollouts.high_level import evaluate, make_eval_env

    def make(name: str, object: str = "sphere", episodes: int = 1, max_episode_steps: int = 5):
        root = tmp_path_factory.mktemp(name) / name
        create_dataset(root, name=name, source="high_level_evaluation", seed=0, config={})
        env = make_eval_env(object, 0.02, "privileged", record_dir=root, max_episode_steps=max_episode_steps)
        try:
            evaluate(RandomPolicy(), env, episodes, 0, progress=False, label="random")
        finally:
            env.close()
        return root

    return make
