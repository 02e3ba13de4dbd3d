"""Shared fixtures: scenes are compiled once per session (each compile takes ~50 ms)."""

from __future__ import annotations

import hashlib
import os

import numpy as np
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


@pytest.fixture(scope="session", autouse=True)
def registration_grids_built_once():
    """Every env's perception builds ``CanonicalRegistration``, whose three nearest-point voxel maps
    (``registration._GridNearest``) take ~1 s to compute and are the same for the same model points:
    here each map is computed once per session and shared, as ``with_search`` copies share them. The
    suite builds a few hundred registrations (338 in-process), most of them of the shipped tool."""
    from hingelab.perception.registration import _GridNearest

    compute = _GridNearest.__init__
    built = {}

    def share(self, points, resolution, margin):
        points = np.array(points)  # the map's own copy: the caller's array stays as it was
        key = (points.shape, points.dtype.str, hashlib.sha256(points.tobytes()).hexdigest(), float(resolution),
               float(margin))
        if key not in built:  # (not set read-only: numba would compile its kernels again for such arrays)
            built[key] = first = object.__new__(_GridNearest)
            compute(first, points, resolution, margin)
        self.__dict__.update(built[key].__dict__)  # the same arrays; still a _GridNearest (pickles as one)

    _GridNearest.__init__ = share
    yield
    _GridNearest.__init__ = compute


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
