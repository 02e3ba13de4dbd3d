"""The rollout envs of a SAC run: seeded episodes, recorded as MCAP, one process per env.

Every episode's seed comes from (run seed, env index, episode count), not from an RNG
that runs on: a run that resumes from a checkpoint knows the count and replays the same
episodes, and 1 or N parallel envs give each env the same episode sequence. The env is
built from the run's config (``config.env_id``, ``config.env_arguments()``), in a spawned
worker from the config's class and its dict.
"""

from __future__ import annotations

import functools
from pathlib import Path

import gymnasium as gym
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from hingelab.envs.recording import RecordingWrapper
from hingelab.envs.vec_env import PinnedVecEnv
from hingelab.seeds import training_episode_seed
from hingelab.sim.object_families import check_object


class SeededEpisodes(gym.Wrapper):
    """Resets with ``training_episode_seed(run_seed, env_index, episodes_started)``;
    ``episodes_started`` is the state."""

    def __init__(self, env: gym.Env, run_seed: int, env_index: int, episodes_started: int = 0):
        super().__init__(env)
        self.run_seed, self.env_index = run_seed, env_index
        self.episodes_started = episodes_started

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = training_episode_seed(self.run_seed, self.env_index, self.episodes_started)
        self.episodes_started += 1
        return self.env.reset(seed=seed, options=options)


def _make_training_env(config_class, config_dict: dict, dataset_dir: str | None, env_index: int) -> gym.Env:
    torch.set_num_threads(1)  # the encoder is small; one thread per env process
    config = config_class.from_dict(config_dict)
    env = gym.make(config.env_id, **config.env_arguments())
    if dataset_dir is not None:
        env = RecordingWrapper(env, dataset_dir, source=config.train_source, action_level=config.action_level,
                               extra_metadata={"env_index": str(env_index), **config.recording_metadata()})
    return SeededEpisodes(env, config.seed, env_index)


def make_training_vec_env(config, dataset_dir: Path | None):
    """``config.n_envs`` seeded envs: one process each (spawned, each held to a core, arrays through
    shared memory: ``PinnedVecEnv``), or all in this process (asked to, or one env unless the run overlaps
    its updates with the env steps: ``hingelab.learners.sac.overlap``)."""

    arguments = config.env_arguments()
    if "object" in arguments:  # a bad object: one line here, not a worker's traceback
        check_object(arguments["object"], arguments["size"], arguments.get("mass", 0.01))
    factories = [functools.partial(_make_training_env, type(config), config.to_dict(),
                                   None if dataset_dir is None else str(dataset_dir), i)
                 for i in range(config.n_envs)]
    if not config.subprocess_envs or (config.n_envs == 1 and not getattr(config, "overlap", False)):
        return DummyVecEnv(factories)
    return PinnedVecEnv(factories, start_method="spawn")


def episode_counts(vec_env) -> list[int]:
    return [int(n) for n in vec_env.get_attr("episodes_started")]


def set_episode_counts(vec_env, counts: list[int]) -> None:
    for i, count in enumerate(counts):
        vec_env.set_attr("episodes_started", int(count), indices=[i])


__all__ = ["SeededEpisodes", "make_training_vec_env", "episode_counts", "set_episode_counts"]
