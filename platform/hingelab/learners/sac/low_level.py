"""``train_low``: SAC on ``hingelab/ToolShape-v0``, dataset-first, resumable.

The run folder and the loop are the training core's (``hingelab.learners.sac.run``);
this module gives the low level's pieces:

* evaluations on fixed held-out goals (``evaluation_goals``: 4 per third of the reachable
  opening range by default), deterministic actions; ``metrics.csv`` rows carry
  ``success_rate`` (the env's verdict, settled over the last 0.5 s: ``rollouts.low_level.summarize``),
  the final latent distance and the tool's drift; the best model is the most successful,
  then the closest;
* checkpoints record ToolShape-v0's arguments and action scale (``env_record``), the
  encoder's fingerprint, and what ``PolicyLowLevel`` rebuilds the low level from;
* ``--from`` datasets: replay pre-fill, demonstrations (``DemoSAC``: BC pre-training and the
  actor's BC term), or offline training (``--offline N``: updates from the datasets alone);
* ``--init-from``: a trained low-level policy's weights start a new run.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import torch
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.logger import Logger
from tqdm import tqdm

from hingelab.envs.low_level import PolicyLowLevel
from hingelab.errors import ConfigError
from hingelab.learners.sac.demo_sac import Demonstrations
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
from hingelab.learners.sac.run import SACRun, algorithm_class, sac_arguments
from hingelab.perception.encoder import shipped_encoder_fingerprint
from hingelab.rollouts.low_level import evaluate, make_eval_env, summarize
from hingelab.rollouts.low_level_goals import evaluation_goals
from hingelab.training.buffer_fill import fill_from_transitions, read_transitions


def build_model(config: LowLevelTrainConfig, env):

    kwargs = {}
    if config.her:
        kwargs = {"replay_buffer_class": HerReplayBuffer,
                  "replay_buffer_kwargs": {"n_sampled_goal": 4, "goal_selection_strategy": "future",
                                           "copy_info_dict": True}}  # the effort term is in the infos
    return algorithm_class(config)("MultiInputPolicy", env, **sac_arguments(config), **kwargs)


def load_initial_weights(model, source) -> None:
    """Start ``model`` from a trained low-level policy (fine-tuning): the actor, critics and their
    targets, the optimizers and the entropy coefficient of ``source``, a ``PolicyLowLevel`` (it
    has refused another task's spaces or another encoder's latents)."""

    if not hasattr(source.model, "get_parameters"):
        raise ConfigError(f"--init-from {source.path} is a goal-region experts manifest; start from one of its "
                          "experts' checkpoints")
    try:
        model.set_parameters(source.model.get_parameters(), exact_match=True, device="cpu")
    except (RuntimeError, ValueError, KeyError) as exc:  # another net_arch, or a plain SAC's optimizers
        raise ConfigError(f"--init-from {source.path} does not fit this run's networks ({exc.__class__.__name__}: "
                          f"{str(exc).splitlines()[0]}); use the net_arch it was trained with") from exc
    if getattr(source.model, "log_ent_coef", None) is not None and getattr(model, "log_ent_coef", None) is not None:
        with torch.no_grad():  # a tensor, not a module: set_parameters leaves it
            model.log_ent_coef.copy_(source.model.log_ent_coef)


class LowLevelRun(SACRun):
    label = "train low"
    dataset_description = "every training rollout of a hingelab train low run"

    def initial_best(self) -> dict:
        return {"success_rate": -1.0, "final_latent_distance": math.inf}

    def is_better(self, row: dict) -> bool:
        return (row["success_rate"], -row["final_latent_distance"]) > (self.best["success_rate"],
                                                                        -self.best["final_latent_distance"])

    def make_evaluator(self) -> None:
        self.eval_env = make_eval_env(dict(self.config.env_arguments()))
        unwrapped = self.eval_env.unwrapped
        self.goals = evaluation_goals(unwrapped.calibration, unwrapped.reachable_range,
                                      self.config.eval_goals_per_region)

    def evaluate_policy(self) -> dict:
        return summarize(evaluate(self.model, self.eval_env, self.goals))

    def close_evaluator(self) -> None:
        self.eval_env.close()

    def env_record(self) -> dict:
        return {**super().env_record(), "action_scale": float(self.eval_env.unwrapped.action_scale)}

    def provenance(self, extra: dict | None = None) -> dict:

        # the envs perceive through the shipped encoder: its latents are what the policy learned
        return super().provenance({"encoder_fingerprint": shipped_encoder_fingerprint(), **(extra or {})})

    def build_model(self, env):
        return build_model(self.config, env)

    def prepare_new_run(self) -> None:
        self.init_source = None
        if self.config.init_from:  # read (and a bad one refused) before the run folder is made

            self.init_source = PolicyLowLevel(self.config.init_from)

    def start_new_model(self) -> None:
        if getattr(self, "init_source", None) is not None:
            load_initial_weights(self.model, self.init_source)

    def use_datasets(self, new_run: bool) -> None:
        """The --from datasets, read once: replay pre-fill (new runs) and demonstrations (BC
        pre-training for new runs, the actor's BC term for every session of the run)."""
        demos = self.config.learns_from_demonstrations
        if not self.config.from_datasets or not (new_run or demos):
            return

        started = time.perf_counter()
        transitions, episodes = read_transitions(self.config.from_datasets, progress=self.progress)
        read_s = time.perf_counter() - started
        if demos:  # before the pre-fill relabels rewards: demonstrations need only observations and actions

            self.model.set_demonstrations(Demonstrations.from_transitions(transitions))
            if new_run and self.config.bc_pretrain_updates:
                self.model.pretrain_actor(self.config.bc_pretrain_updates, self.config.batch_size,
                                          fit_std=self.config.bc_pretrain_std)
        if new_run:
            # rewards recomputed with this run's reward (the datasets may be recorded with or without effort)
            self.prefill = fill_from_transitions(self.model.replay_buffer, transitions, episodes,
                                                 len(self.config.from_datasets), read_s, self.eval_env.unwrapped)

    def summary_extra(self) -> dict:
        return {"eval_goals": len(self.goals)}

    # ------------------------------------------------------------------ offline
    def train(self) -> dict:
        if self.config.offline_updates:
            return self._train_offline()
        return super().train()

    def _train_offline(self) -> dict:

        model, total = self.model, self.config.offline_updates
        model.set_logger(Logger(folder=None, output_formats=[]))  # no SB3-<time> temp folder
        model._setup_learn(0, callback=None, reset_num_timesteps=False)
        done_updates = model._n_updates
        chunk = max(1, min(self.config.eval_every, 1000))
        start = time.perf_counter()
        if done_updates == 0:
            self.evaluate_now(0, {"updates": 0, "wall_time_s": 0.0, "offline": 1})
        with tqdm(total=total, initial=done_updates, desc="offline updates", unit="update",
                  disable=not self.progress) as bar:
            while model._n_updates < total:
                n = min(chunk, total - model._n_updates)
                model.train(gradient_steps=n, batch_size=self.config.batch_size)
                bar.update(n)
                if model._n_updates % self.config.eval_every < n or model._n_updates == total:
                    row = self.evaluate_now(model._n_updates, {"updates": model._n_updates, "offline": 1,
                                                               "wall_time_s": time.perf_counter() - start})
                    bar.set_postfix(success=f"{row['success_rate']:.2f}")
        return self.finish(time.perf_counter() - start)


def train_low(config: LowLevelTrainConfig, run_dir, resume: bool = False, progress: bool = True,
              name: str | None = None) -> dict:
    """Train (or resume) a low-level run; returns a summary dict (see ``SACRun.finish``)."""
    return LowLevelRun(config, Path(run_dir), resume=resume, progress=progress, name=name).setup().train()
