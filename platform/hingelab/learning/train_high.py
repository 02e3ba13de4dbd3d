"""``train_high`` and ``train_flat``: SAC on ToolPick-v0 (a frozen low level inside) and on the
flat baseline ToolPickFlat-v0, on the training core (``hingelab.learning.sac_run``).

The high level's pieces:

* the privileged prior (``prepare_data``): heuristic demos, from ``--from`` or generated into
  ``RUNDIR/prior`` (``--prior-episodes``, seed ``PRIOR_SEED_BASE + run seed``), turned into
  transitions of ToolPick-v0's spaces with the run's reward (``high_level_transitions``; the
  demo action is the reached latent, ``--demo-lookahead`` steps on, and the recorded hand
  velocity). They go into a ``DemoShareReplayBuffer`` (``--demo-share`` of every batch) or, with
  ``--demo-share 0``, through the buffer's own ``add`` into the ring buffer (the paper's plain
  pre-fill); with ``--bc-weight``/``--bc-pretrain`` also into ``DemoSAC``'s BC term. The choice
  is in the run's config.json.
* evaluations: ``--eval-episodes`` held-out episodes (seeds ``episode_seed(EVAL_SEED, i)`` of
  ``hingelab eval high``, never a training or pick-table seed), deterministic actions;
  ``metrics.csv`` rows carry ``success_rate`` (within the 200 steps), ``first_attempt_success_rate``,
  ``mean_attempts``, the return and the failure reasons;
* checkpoints record the env's arguments, its action scaling, the encoder's fingerprint and the
  low level's sha256 (``high_level_checkpoint`` refuses the policy beside another low level).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError
from hingelab.learning.high_level_config import FlatTrainConfig, HighLevelTrainConfig
from hingelab.learning.sac_run import SACRun, algorithm_class, sac_arguments

PRIOR_DIR = "prior"
PRIOR_SEED_BASE = 700_000  # the generated prior's `generate heuristic` seed: run seed + this
EVAL_SEED = 77  # held-out evaluations during training: `hingelab eval high --seed 77`'s episodes


def summarize_pick(episodes) -> dict:
    """One metrics row of a ToolPick evaluation table (``high_level_eval.evaluate``)."""
    from hingelab.learning.high_level_eval import FAILURE_REASONS

    row = {"success_rate": float(episodes["success"].mean()),
           "first_attempt_success_rate": float(episodes["first_attempt_success"].mean()),
           "mean_attempts": float(episodes["attempts"].mean()), "return": float(episodes["return"].mean()),
           "mean_length": float(episodes["length"].mean()),
           "final_object_target_distance_m": float(episodes["object_target_distance_m"].median())}
    for reason in FAILURE_REASONS:
        row[f"failures_{reason}"] = int((episodes["failure_reason"] == reason).sum())
    return row


class HighLevelRun(SACRun):
    label = "train high"
    dataset_description = "every training rollout of a hingelab train high run"

    # ------------------------------------------------------------------ data
    def prepare_new_run(self) -> None:
        from hingelab.envs.low_level import resolve_low_level

        if self.config.low_level != "none":
            resolve_low_level(self.config.low_level)  # a bad --low-level: an error before the folder
        for root in self.config.from_datasets:
            if not Path(root).exists():
                raise ConfigError(f"--from {root} does not exist; give a heuristic dataset "
                                  "(hingelab generate heuristic) or drop --from to generate one")

    def prior_datasets(self) -> list[str]:
        """The demos' datasets: --from, or the prior the run generates (once; a resumed run reuses it)."""
        if self.config.from_datasets:
            return [str(p) for p in self.config.from_datasets]
        root = self.run_dir / PRIOR_DIR
        if not (root / "dataset.json").exists() or not any((root / "episodes").glob("*.mcap")):
            import shutil

            from hingelab.heuristic.rollout import HeuristicRunConfig, generate_heuristic_dataset

            shutil.rmtree(root, ignore_errors=True)  # a generation cut short is made again
            generate_heuristic_dataset(root, HeuristicRunConfig(
                episodes=self.config.prior_episodes, object=self.config.object, size=self.config.size,
                mass=self.config.mass, seed=PRIOR_SEED_BASE + self.config.seed, randomize=self.config.randomize,
                max_episode_steps=self.config.max_episode_steps), progress=self.progress,
                name=f"{self.name}-prior")
        return [str(root)]

    def prepare_data(self) -> None:
        self.demos = None
        if not self.config.prior:
            return
        from hingelab.learning.high_level_prefill import high_level_transitions, look_ahead

        started = time.perf_counter()
        datasets = self.prior_datasets()
        transitions = high_level_transitions(datasets, self.config.reward, actions=self.config.demo_actions)
        self.demos = look_ahead(transitions, self.config.demo_lookahead)
        self.demo_info = {"datasets": datasets, "transitions": len(self.demos),
                          "episodes": int(len(np.unique(self.demos.episode_index))),
                          "seconds": round(time.perf_counter() - started, 2)}

    def build_model(self, env):
        kwargs = sac_arguments(self.config)
        if self.demos is not None and self.config.demo_share > 0:
            from hingelab.learning.high_level_prefill import DemoShareReplayBuffer

            kwargs.update(replay_buffer_class=DemoShareReplayBuffer,
                          replay_buffer_kwargs={"demos": self.demos, "demo_share": self.config.demo_share})
        model = algorithm_class(self.config)("MlpPolicy", env, **kwargs)
        if self.demos is not None and self.config.demo_share > 0:
            model.replay_buffer_kwargs = {"demo_share": self.config.demo_share}  # the zip does not carry the demos
        return model

    def start_new_model(self) -> None:
        if self.demos is None:
            return
        if self.config.demo_share == 0:  # the paper's plain pre-fill, through the buffer's own add
            from hingelab.learning.high_level_prefill import fill_high_level_buffer

            method = "add" if self.config.n_envs == 1 else "bulk"
            fill_high_level_buffer(self.model.replay_buffer, self.demos, method=method)

    def use_datasets(self, new_run: bool) -> None:
        if self.demos is None or not self.config.learns_from_demonstrations:
            return
        from hingelab.learning.demo_sac import Demonstrations

        self.model.set_demonstrations(Demonstrations.from_transitions(self.demos))
        if new_run and self.config.bc_pretrain_updates:
            self.model.pretrain_actor(self.config.bc_pretrain_updates, self.config.batch_size)

    # ------------------------------------------------------------------ evaluation
    def make_evaluator(self) -> None:
        import gymnasium as gym

        from hingelab.learning.high_level_eval import FailureReasonWrapper

        self.eval_env = FailureReasonWrapper(gym.make(self.config.env_id, **self.config.env_arguments()))

    def evaluate_policy(self) -> dict:
        from hingelab.learning.high_level_eval import ModelPolicy, evaluate

        return summarize_pick(evaluate(ModelPolicy(self.model), self.eval_env, self.config.eval_episodes, EVAL_SEED))

    def is_better(self, row: dict) -> bool:
        return (row["success_rate"], row["first_attempt_success_rate"], row["return"]) > (
            self.best["success_rate"], self.best["first_attempt_success_rate"], self.best["return"])

    def initial_best(self) -> dict:
        return {"success_rate": -1.0, "first_attempt_success_rate": -1.0, "return": -np.inf}

    def close_evaluator(self) -> None:
        self.eval_env.close()

    # ------------------------------------------------------------------ records
    def env_record(self) -> dict:
        from hingelab.envs.tool_pick import MAX_SPEED, Z_SCALE

        return {**super().env_record(), "action_scale": {"z_goal": Z_SCALE, "hand_velocity_m_s": MAX_SPEED}}

    def provenance(self, extra: dict | None = None) -> dict:
        from hingelab.learning.high_level_checkpoint import training_context

        prior = None if self.demos is None else {**self.demo_info, "demo_share": self.config.demo_share,
                                                  "demo_actions": self.config.demo_actions,
                                                  "demo_lookahead": self.config.demo_lookahead}
        return super().provenance({**training_context(self.config.low_level), "prior": prior, **(extra or {})})

    def summary_extra(self) -> dict:
        return {"prior": None if self.demos is None else self.demo_info, "eval_episodes": self.config.eval_episodes}


class FlatRun(HighLevelRun):
    label = "train flat"
    dataset_description = "every training rollout of a hingelab train flat run"

    def env_record(self) -> dict:
        from hingelab.envs.tool_pick import MAX_SPEED
        from hingelab.envs.tool_pick_flat import FINGER_SCALE

        return {**SACRun.env_record(self), "action_scale": {"fingers_rad": FINGER_SCALE, "hand_velocity_m_s": MAX_SPEED}}


def train_high(config: HighLevelTrainConfig, run_dir, resume: bool = False, progress: bool = True,
               name: str | None = None) -> dict:
    """Train (or resume) a high-level run (or, with a ``FlatTrainConfig``, a flat one); a summary dict."""
    cls = FlatRun if isinstance(config, FlatTrainConfig) else HighLevelRun
    return cls(config, Path(run_dir), resume=resume, progress=progress, name=name).setup().train()
