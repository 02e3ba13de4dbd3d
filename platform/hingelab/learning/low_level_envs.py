"""The training and evaluation envs of a low-level run: seeded episodes, recorded as MCAP.

Every episode's seed comes from (run seed, env index, episode count), not from an RNG
that runs on: a run that resumes from a checkpoint knows the count and replays the same
episodes, and 1 or N parallel envs give each env the same episode sequence.
"""

from __future__ import annotations

import functools
from pathlib import Path

import gymnasium as gym
import numpy as np

from hingelab.learning.low_level_config import ENV_ID, LowLevelTrainConfig

TRAIN_SOURCE = "low_level_training"
EVAL_SEED_BASE = 2_000_000_000  # held-out episode seeds, far from any training seed


def episode_seed(run_seed: int, env_index: int, episode: int) -> int:
    return (run_seed * 1_000_003 + env_index * 100_003 + episode * 7919) % EVAL_SEED_BASE


class SeededEpisodes(gym.Wrapper):
    """Resets with ``episode_seed(run_seed, env_index, episodes_started)``; ``episodes_started`` is the state."""

    def __init__(self, env: gym.Env, run_seed: int, env_index: int, episodes_started: int = 0):
        super().__init__(env)
        self.run_seed, self.env_index = run_seed, env_index
        self.episodes_started = episodes_started

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = episode_seed(self.run_seed, self.env_index, self.episodes_started)
        self.episodes_started += 1
        return self.env.reset(seed=seed, options=options)


def _make_training_env(config_dict: dict, dataset_dir: str | None, env_index: int) -> gym.Env:
    import torch

    import hingelab  # noqa: F401  (registers the envs in a spawned worker)
    from hingelab.envs.recording import RecordingWrapper

    torch.set_num_threads(1)  # the encoder is small; one thread per env process
    config = LowLevelTrainConfig.from_dict(config_dict)
    env = gym.make(ENV_ID, **config.env_arguments())
    if dataset_dir is not None:
        env = RecordingWrapper(env, dataset_dir, source=TRAIN_SOURCE, action_level="low",
                               extra_metadata={"env_index": str(env_index),
                                               "use_effort": str(config.use_effort)})
    return SeededEpisodes(env, config.seed, env_index)


def make_training_vec_env(config: LowLevelTrainConfig, dataset_dir: Path | None):
    """``n_envs`` seeded envs: one process each (spawned, each held to a core, arrays through shared
    memory: ``PinnedVecEnv``), or all in this process (one env, or asked to)."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from hingelab.envs.vec_env import PinnedVecEnv

    factories = [functools.partial(_make_training_env, config.to_dict(),
                                   None if dataset_dir is None else str(dataset_dir), i)
                 for i in range(config.n_envs)]
    if config.n_envs == 1 or not config.subprocess_envs:
        return DummyVecEnv(factories)
    return PinnedVecEnv(factories, start_method="spawn")


def episode_counts(vec_env) -> list[int]:
    return [int(n) for n in vec_env.get_attr("episodes_started")]


def set_episode_counts(vec_env, counts: list[int]) -> None:
    for i, count in enumerate(counts):
        vec_env.set_attr("episodes_started", int(count), indices=[i])


# ---------------------------------------------------------------------------- evaluation goals
REGIONS = ("closed", "middle", "open")  # thirds of the reachable opening range


def evaluation_goals(calibration, reachable_range: tuple[float, float], per_region: int) -> list[dict]:
    """Fixed held-out goals: ``per_region`` openings evenly inside each third of the reachable range.

    Returns dicts with ``region``, ``opening_rad``, ``z_goal`` (2,) and the episode ``seed``.
    """
    low, high = reachable_range
    edges = np.linspace(low, high, len(REGIONS) + 1)
    goals = []
    for r, region in enumerate(REGIONS):
        # centres of per_region equal slices of the third: never on a region edge
        step = (edges[r + 1] - edges[r]) / per_region
        for j in range(per_region):
            opening = float(edges[r] + (j + 0.5) * step)
            goals.append({"region": region, "opening_rad": opening,
                          "z_goal": np.asarray(calibration.z_for_opening(opening), float),
                          "seed": EVAL_SEED_BASE + len(goals)})
    return goals


def region_of(opening: float, reachable_range: tuple[float, float]) -> str:
    low, high = reachable_range
    third = (high - low) / len(REGIONS)
    index = int(np.clip((opening - low) // third, 0, len(REGIONS) - 1))
    return REGIONS[index]
