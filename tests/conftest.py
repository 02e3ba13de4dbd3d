"""Shared fixtures: scenes are compiled once per session (each compile takes ~50 ms)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session", autouse=True)
def torch_on_one_thread():
    """Tests train tiny nets, where a second OpenMP thread only spins (and crawls when the other core
    is busy); one intra-op thread is also what a run sets by default (``--threads 1``). Session-scoped
    so that module-scoped fixtures (a tiny run shared by a file's tests) train on it too."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(autouse=True)
def back_to_one_torch_thread(torch_on_one_thread):
    """Each test starts on one thread again, whatever the test before it set (``train encoder --threads``)."""
    import torch

    torch.set_num_threads(1)


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
