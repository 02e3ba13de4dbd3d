"""What a run on ToolPick-v0 does besides learning, shared by its learners (SAC, the phase clone):
the privileged prior's demos (``PriorData``) and the held-out evaluation (``PickEvaluation``).

* ``PriorData``: the demos' datasets, ``--from`` or the prior the run generates once into
  ``RUNDIR/prior`` (``hingelab.training.prior``), turned into transitions of ToolPick-v0's spaces with
  the run's reward (``high_level_transitions``; the demo action is the recorded command, or the reached
  latent ``--demo-lookahead`` steps on, and the recorded hand velocity); what filled them goes into
  config.json under ``prior``.
* ``PickEvaluation``: ``--eval-episodes`` held-out episodes (seeds ``eval_high_seed(TRAINING_EVALUATION_SEED, i)`` of
  ``hingelab eval high``, never a training or pick-table seed), deterministic actions; a metrics row
  of the pick table's rates, the return, the length and the final object-target distance.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

from hingelab.analysis.pick_table import pick_rates
from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError
from hingelab.policies import ModelPolicy
from hingelab.policies.low_level import resolve_low_level
from hingelab.policies.phase_clone import PhaseClone, net_from_state, net_state
from hingelab.rollouts.high_level import FailureReasonWrapper, evaluate
from hingelab.seeds import TRAINING_EVALUATION_SEED
from hingelab.tasks import observation_dim
from hingelab.training.high_level_demos import concat_demos, high_level_transitions, look_ahead
from hingelab.training.prior import generate_prior, prior_parts
from hingelab.training.run_folder import RunFolder
from hingelab.training.torch_process import configure_torch
from hingelab.workers.job_pool import chunks

PRIOR_DIR = "prior"
EVAL_SEED = TRAINING_EVALUATION_SEED


def summarize_pick(episodes) -> dict:
    """One metrics row of a ToolPick evaluation table (``rollouts.high_level.evaluate``): the pick table's
    rates (``pick_rates``, without the interval columns), the return, the length, the final distance."""
    rates = {k: v for k, v in pick_rates(episodes).items()
             if k in ("success_rate", "first_attempt_success_rate", "mean_attempts") or k.startswith("failures_")}
    return {**rates, "return": float(episodes["return"].mean()), "mean_length": float(episodes["length"].mean()),
            "final_object_target_distance_m": float(episodes["object_target_distance_m"].median())}


def prior_dataset_record(root, transitions, mode: str, skipped: list) -> dict:
    """What one demo dataset gave: its source, episodes, transitions, actions, left-out episodes."""
    card = Dataset(root).card
    record = {"path": str(root), "source": card.source, "name": card.name, "transitions": len(transitions),
              "episodes": int(len(np.unique(transitions.episode_index))), "demo_actions": mode,
              "skipped": [{"episode": path, "reason": reason} for path, reason in skipped]}
    if "demo_action_recorded" in transitions.infos:  # real episodes: the rig's command or the reached action
        record["transitions_with_recorded_action"] = int(transitions.infos["demo_action_recorded"].sum())
    return record


def check_pick_inputs(config) -> None:
    """Checks before a new run's folder is written: the low level and the --from datasets exist."""
    if config.low_level != "none":
        resolve_low_level(config.low_level)  # a bad --low-level: an error before the folder
    for root in getattr(config, "from_datasets", ()):
        if not Path(root).exists():
            raise ConfigError(f"--from {root} does not exist; give a heuristic dataset "
                              "(hingelab generate heuristic), a ToolPick-v0 recording or real episodes "
                              "(hingelab datasets import-ros2), or drop --from to generate one")


class PriorData:
    """The demos of a run with a ``PriorDemos`` config part; ``load()`` sets ``demos`` and ``info``."""

    def __init__(self, config, run_dir: Path, name: str, progress: bool, pool=None):
        self.config, self.run_dir, self.name, self.progress = config, Path(run_dir), name, progress
        self.pool = pool  # a JobPool: the prior generated in its workers
        self.demos = self.info = None
        self.modes: list[str] = []

    def datasets(self) -> list[str]:
        """--from, or the prior the run generates (once; a resumed run reuses it when every dataset holds all
        its episodes: a generation cut off, in any of its datasets, is made again)."""
        if self.config.from_datasets:
            return [str(p) for p in self.config.from_datasets]
        root = self.run_dir / PRIOR_DIR
        parts = [(root / folder, episodes) for folder, _, _, episodes in prior_parts(self.config)]
        if not all((r / "dataset.json").exists() and len(list((r / "episodes").glob("*.mcap"))) == episodes
                   for r, episodes in parts):
            roots = generate_prior(root, self.config, name=f"{self.name}-prior", progress=self.progress,
                                   pool=self.pool)
        else:
            roots = [r for r, _ in parts]
        return [str(r) for r in roots]

    def action_mode(self, root) -> str:
        """--demo-actions, or for auto: the recorded command of scripted demos, the reached latent otherwise."""
        if self.config.demo_actions != "auto":
            return self.config.demo_actions
        card = Dataset(root).card
        if card.source == "real":  # the rig's own command where it recorded one (real_demos)
            return "recorded"
        policy = (card.config or {}).get("policy")
        return "recorded" if policy in ("scripted", "scripted-feedback") else "reached"

    def load(self) -> None:
        started = time.perf_counter()
        datasets = self.datasets()
        self.modes = [self.action_mode(root) for root in datasets]
        parts, offset, filled = [], 0, []
        extent = bool(self.config.env_kwargs.get("observe_extent", False))
        for root, mode in zip(datasets, self.modes):
            skipped = []  # real episodes that lack what the relabelling needs: left out, named below
            part = high_level_transitions([root], self.config.reward, actions=mode,
                                          observation_dim=observation_dim(extent), skipped=skipped,
                                          encoder_path=self.config.env_kwargs.get("encoder_path"))
            part.episode_index = part.episode_index + offset  # one numbering over the datasets (look_ahead)
            offset = int(part.episode_index.max()) + 1
            parts.append(part)
            filled.append(prior_dataset_record(root, part, mode, skipped))
            if skipped:
                print(f"--from {root}: left out {len(skipped)} real episode(s) that cannot be relabelled "
                      f"(listed in {self.run_dir}/config.json under prior); the first: {skipped[0][1]}")
        self.demos = look_ahead(concat_demos(parts) if len(parts) > 1 else parts[0], self.config.demo_lookahead)
        self.info = {"datasets": datasets, "demo_actions": self.modes, "transitions": len(self.demos),
                     "episodes": int(len(np.unique(self.demos.episode_index))),
                     "sources": sorted({d["source"] for d in filled}), "filled_from": filled,
                     "seconds": round(time.perf_counter() - started, 2)}


def open_prior_run(config, run_dir, learner: str, resume: bool, progress: bool, name: str | None, pool=None):
    """The opening of a run that learns from the privileged prior (the phase clone, DAgger): the run folder (new,
    after ``check_pick_inputs``, or resumed), torch's threads, the prior's demos loaded (generated in ``pool``'s
    workers, a ``JobPool``, if given) and, in a new run, recorded in ``config.json``. Returns (folder, prior);
    ``folder.config`` is the run's config."""
    folder = RunFolder(Path(run_dir), config, resume=resume, name=name)
    configure_torch(folder.config.torch_threads)
    if not resume:
        check_pick_inputs(folder.config)
        folder.write_run_files({"learner": learner})
    prior = PriorData(folder.config, folder.path, folder.name, progress, pool=pool)
    prior.load()
    if not resume:
        folder.record_run_fact("prior", prior.info)
    return folder, prior


class PickEvaluation:
    """Held-out evaluations of a policy on the run's ToolPick task (or its flat version). With ``pool`` (a
    ``hingelab.workers.job_pool.JobPool``), a phase clone's episodes run in its workers, a few contiguous blocks
    each, and their rows, merged in episode order, make the same metrics row."""

    def __init__(self, config, pool=None):
        self.config, self.pool = config, pool
        self.env = None if pool is not None else self._make_env()  # (with a pool: made if a model needs it here)

    def _make_env(self):
        return FailureReasonWrapper(gym.make(self.config.env_id, **self.config.env_arguments()))

    def __call__(self, model) -> dict:
        if self.pool is None or not isinstance(model, PhaseClone):
            if self.env is None:
                self.env = self._make_env()
            return summarize_pick(evaluate(ModelPolicy(model), self.env, self.config.eval_episodes, EVAL_SEED))
        nets = [net_state(net) for net in model.nets]
        blocks = chunks(self.config.eval_episodes, EVAL_BLOCKS_PER_JOB * self.pool.jobs)
        parts = self.pool.map(_evaluate_block, [{"config": self.config, "nets": nets, "indices": block}
                                                for block in blocks])
        return summarize_pick(pd.concat(parts, ignore_index=True).sort_values("episode", ignore_index=True))

    @staticmethod
    def initial_best() -> dict:
        return {"success_rate": -1.0, "first_attempt_success_rate": -1.0, "return": -np.inf}

    @staticmethod
    def is_better(row: dict, best: dict) -> bool:
        return (row["success_rate"], row["first_attempt_success_rate"], row["return"]) > (
            best["success_rate"], best["first_attempt_success_rate"], best["return"])

    def close(self) -> None:
        if self.env is not None:
            self.env.close()


EVAL_BLOCKS_PER_JOB = 3  # blocks of an evaluation per worker: a worker done early takes another
_WORKER_ENVS: dict = {}  # a worker's evaluation envs, by their arguments: made once per run


def _evaluate_block(job: dict) -> pd.DataFrame:
    """A ``--jobs`` worker's block of a held-out evaluation (``PickEvaluation``): its episodes' rows."""
    config = job["config"]
    key = json.dumps([config.env_id, config.env_arguments()], sort_keys=True, default=str)
    if key not in _WORKER_ENVS:
        _WORKER_ENVS[key] = FailureReasonWrapper(gym.make(config.env_id, **config.env_arguments()))
    model = PhaseClone([net_from_state(state) for state in job["nets"]])
    return evaluate(ModelPolicy(model), _WORKER_ENVS[key], config.eval_episodes, EVAL_SEED, indices=job["indices"])


__all__ = ["PRIOR_DIR", "EVAL_SEED", "summarize_pick", "prior_dataset_record", "check_pick_inputs", "PriorData",
           "open_prior_run",
           "PickEvaluation"]
