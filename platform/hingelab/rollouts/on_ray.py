"""``hingelab eval low|high --ray``: the evaluation episodes as Ray tasks (``hingelab.workers.ray_fan_out``).

The runners rebuild, once per Ray worker process, what the local evaluation builds once: the
recording env (writing into the evaluation's dataset folder) and the policy (from its checkpoint
path, or a baseline by name). Each task runs one episode from its own seed and returns its row of
``episodes.csv``; rows go into the evaluation's journal as they arrive, so a stopped ``--ray``
evaluation resumes like a local one, and the rows come back in the local evaluation's order.
"""

from __future__ import annotations

import functools
from pathlib import Path

import pandas as pd
import torch

from hingelab.envs.low_level import PolicyLowLevel
from hingelab.policies import ModelPolicy, load_policy
from hingelab.rollouts import high_level as H
from hingelab.rollouts import low_level as L
from hingelab.seeds import eval_high_seed
from hingelab.workers.ray_fan_out import fan_out


def _one_thread() -> None:
    torch.set_num_threads(1)  # one core per task


class LowLevelEpisodes:
    """One ``eval low`` episode per call (a goal dict of ``rollouts.low_level.sampled_goals``)."""

    def __init__(self, env_arguments: dict, dataset_dir: str, checkpoint: str | None, baseline: str | None):
        self.env_arguments, self.dataset_dir = env_arguments, dataset_dir
        self.checkpoint, self.baseline = checkpoint, baseline
        self.env = self.policy = None

    def __call__(self, goal: dict) -> dict:
        if self.env is None:
            _one_thread()
            self.env = L.make_eval_env(self.env_arguments, record_dir=Path(self.dataset_dir))
            if self.baseline:
                self.policy = load_policy(self.baseline, env=self.env)
            else:
                self.policy = PolicyLowLevel(self.checkpoint).model
        self.env.extra_metadata = {"goal_region": goal["region"], "goal_opening_rad": f"{goal['opening_rad']:.5f}"}
        return L.run_episode(self.policy, self.env, goal)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def evaluate_low_on_ray(goals: list[dict], env_arguments: dict, out: Path, checkpoint, baseline: str | None,
                        journal, address: str, progress: bool = True) -> pd.DataFrame:
    """``rollouts.low_level.evaluate_sampled_goals`` with the episodes as Ray tasks."""
    rows = list(journal.rows)
    done = {int(r["seed"]) for r in rows}
    todo = [g for g in goals if int(g["seed"]) not in done]
    factory = functools.partial(LowLevelEpisodes, env_arguments, str(Path(out).resolve()),
                                None if checkpoint is None else str(Path(checkpoint).resolve()), baseline)
    _run(factory, todo, journal, rows, address, progress, "eval low")
    order = {int(g["seed"]): k for k, g in enumerate(goals)}
    return pd.DataFrame(rows).sort_values("seed", key=lambda s: s.map(order), ignore_index=True)


class HighLevelEpisodes:
    """One ``eval high`` episode per call (an episode index)."""

    def __init__(self, env_options: dict, dataset_dir: str, seed: int, checkpoint: str | None,
                 baseline: str | None):
        self.env_options, self.dataset_dir, self.seed = env_options, dataset_dir, seed
        self.checkpoint, self.baseline = checkpoint, baseline
        self.env = self.policy = None

    def __call__(self, index: int) -> dict:
        if self.env is None:
            _one_thread()
            self.env = H.make_eval_env(record_dir=Path(self.dataset_dir), **self.env_options)
            if self.baseline:
                self.policy = load_policy(self.baseline)
            else:
                self.policy = ModelPolicy(load_policy(Path(self.checkpoint), level="high"))
            self.base_metadata = dict(self.env.extra_metadata)
        self.env.extra_metadata = {**self.base_metadata, "episode_index": str(index)}
        return {"episode": index, **H.run_episode(self.policy, self.env, eval_high_seed(self.seed, index))}

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def evaluate_high_on_ray(episodes: int, seed: int, env_options: dict, out: Path, checkpoint, baseline: str | None,
                         journal, address: str, progress: bool = True) -> pd.DataFrame:
    """``rollouts.high_level.evaluate`` with the episodes as Ray tasks; ``env_options``: the keyword arguments
    of ``rollouts.high_level.make_eval_env`` besides ``record_dir``."""
    rows = list(journal.rows)
    done = {int(r["episode"]) for r in rows}
    todo = [i for i in range(episodes) if i not in done]
    if env_options["low_level"] not in ("policy", "privileged") and Path(env_options["low_level"]).exists():
        # a low-level checkpoint, found from the workers' own working folders too
        env_options = {**env_options, "low_level": str(Path(env_options["low_level"]).resolve())}
    factory = functools.partial(HighLevelEpisodes, env_options, str(Path(out).resolve()), seed,
                                None if checkpoint is None else str(Path(checkpoint).resolve()), baseline)
    _run(factory, todo, journal, rows, address, progress, "eval high")
    return pd.DataFrame(rows).sort_values("episode", ignore_index=True)


def _run(factory, items, journal, rows: list, address: str, progress: bool, desc: str) -> None:
    def keep(row: dict) -> None:
        journal.append(row)
        rows.append(row)

    fan_out(factory, items, address=address, on_result=keep, progress=progress, desc=desc)


__all__ = ["LowLevelEpisodes", "HighLevelEpisodes", "evaluate_low_on_ray", "evaluate_high_on_ray"]
