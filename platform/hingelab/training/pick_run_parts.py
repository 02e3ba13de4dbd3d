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

import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from hingelab.analysis.pick_table import pick_rates
from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError
from hingelab.policies import ModelPolicy
from hingelab.policies.low_level import resolve_low_level
from hingelab.rollouts.high_level import FailureReasonWrapper, evaluate
from hingelab.seeds import TRAINING_EVALUATION_SEED
from hingelab.tasks import observation_dim
from hingelab.training.high_level_demos import concat_demos, high_level_transitions, look_ahead
from hingelab.training.prior import generate_prior, prior_parts
from hingelab.training.run_folder import RunFolder
from hingelab.training.torch_process import configure_torch

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

    def __init__(self, config, run_dir: Path, name: str, progress: bool):
        self.config, self.run_dir, self.name, self.progress = config, Path(run_dir), name, progress
        self.demos = self.info = None
        self.modes: list[str] = []

    def datasets(self) -> list[str]:
        """--from, or the prior the run generates (once; a resumed run reuses it)."""
        if self.config.from_datasets:
            return [str(p) for p in self.config.from_datasets]
        root = self.run_dir / PRIOR_DIR
        roots = [root / folder for folder, *_ in prior_parts(self.config)]
        if not all((r / "dataset.json").exists() and any((r / "episodes").glob("*.mcap")) for r in roots):
            roots = generate_prior(root, self.config, name=f"{self.name}-prior", progress=self.progress)
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


def open_prior_run(config, run_dir, learner: str, resume: bool, progress: bool, name: str | None):
    """The opening of a run that learns from the privileged prior (the phase clone, DAgger): the run folder (new,
    after ``check_pick_inputs``, or resumed), torch's threads, the prior's demos loaded and, in a new run,
    recorded in ``config.json``. Returns (folder, prior); ``folder.config`` is the run's config."""
    folder = RunFolder(Path(run_dir), config, resume=resume, name=name)
    configure_torch(folder.config.torch_threads)
    if not resume:
        check_pick_inputs(folder.config)
        folder.write_run_files({"learner": learner})
    prior = PriorData(folder.config, folder.path, folder.name, progress)
    prior.load()
    if not resume:
        folder.record_run_fact("prior", prior.info)
    return folder, prior


class PickEvaluation:
    """Held-out evaluations of a policy on the run's ToolPick task (or its flat version)."""

    def __init__(self, config):
        self.config = config
        self.env = FailureReasonWrapper(gym.make(config.env_id, **config.env_arguments()))

    def __call__(self, model) -> dict:
        return summarize_pick(evaluate(ModelPolicy(model), self.env, self.config.eval_episodes, EVAL_SEED))

    @staticmethod
    def initial_best() -> dict:
        return {"success_rate": -1.0, "first_attempt_success_rate": -1.0, "return": -np.inf}

    @staticmethod
    def is_better(row: dict, best: dict) -> bool:
        return (row["success_rate"], row["first_attempt_success_rate"], row["return"]) > (
            best["success_rate"], best["first_attempt_success_rate"], best["return"])

    def close(self) -> None:
        self.env.close()


__all__ = ["PRIOR_DIR", "EVAL_SEED", "summarize_pick", "prior_dataset_record", "check_pick_inputs", "PriorData",
           "open_prior_run",
           "PickEvaluation"]
