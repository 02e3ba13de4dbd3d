"""The training core of every SAC learner: one run folder, set up new or resumed, trained with
composable callbacks, checkpointed for an exact resume.

``SACRun`` is the whole loop; a learner (``low_level.LowLevelRun``, ``high_level.HighLevelRun``)
subclasses it and gives its task's pieces: the evaluation (``make_evaluator``,
``evaluate_policy``, ``is_better``), what its checkpoints record about the env
(``env_record``), and what it learns from datasets (``use_datasets``).

Checkpoints are taken where every env has just finished an episode (its next episode is
fully determined by its seed and count), after the updates of that step (an overlapped run's
checkpoints record that step's updates as pending: ``hingelab.learners.sac.overlap``): resuming
from one continues the run as if it had never stopped. A checkpoint records the rollouts it covers
(``finished_episodes``, per env); a resume removes the recorded rollouts that finished after it,
which the resumed run replays, so the run's dataset holds each rollout once. Evaluations use held-out seeds with
deterministic actions and do not touch the training RNG.
"""

from __future__ import annotations

from pathlib import Path

import torch
from stable_baselines3 import SAC
from stable_baselines3.common.logger import Logger

from hingelab.episodes.dataset import corrupt_policy
from hingelab.errors import ConfigError
from hingelab.learners.sac.callbacks import CHECKPOINT_PATIENCE_EPISODES, RunClock, run_callbacks
from hingelab.learners.sac.demo_sac import DemoSAC
from hingelab.learners.sac.fast_sac import FastSAC
from hingelab.learners.sac.overlap import lag_record
from hingelab.provenance import code_version
from hingelab.training import checkpoints as ckpt
from hingelab.training import resume_state
from hingelab.training.envs import episode_counts, make_training_vec_env, set_episode_counts
from hingelab.training.run_folder import RunFolder, covered_episodes
from hingelab.training.torch_process import configure_torch

PROVENANCE_ATTRIBUTE = "hingelab_provenance"  # saved inside every model.zip


def algorithm_class(config):
    """SB3's ``SAC``, ``FastSAC``, or ``DemoSAC`` when the run learns from demonstrations."""
    if config.algorithm == "fast_sac":
        if config.learns_from_demonstrations:
            return DemoSAC
        return FastSAC
    return SAC


def sac_arguments(config) -> dict:
    """Keyword arguments of the SAC constructor that every learner shares."""

    kwargs = {"learning_rate": config.learning_rate, "buffer_size": config.buffer_size,
              "learning_starts": config.learning_starts, "batch_size": config.batch_size, "tau": config.tau,
              "gamma": config.gamma, "train_freq": config.train_freq, "gradient_steps": config.gradient_steps,
              "ent_coef": config.ent_coef, "seed": config.seed, "device": "cpu", "verbose": 0,
              "policy_kwargs": {"net_arch": [int(n) for n in config.net_arch], "activation_fn": torch.nn.ReLU}}
    if config.algorithm == "fast_sac" and config.learns_from_demonstrations:
        kwargs.update(bc_weight=config.demo_bc_weight, q_filter=config.demo_q_filter, q_scaled=config.bc_q_scaled)
    update = getattr(config, "update", "eager")  # (configs saved before the option have none)
    if update != "eager":
        kwargs["update"] = update
    return kwargs


class SACRun:
    """One run folder: set up (new or resumed), train, evaluate, checkpoint."""

    label = "train"  # the progress bar's
    learner_name = "sac"  # what config.json records, checked by train's --resume
    dataset_description = "every training rollout of a hingelab run"

    def __init__(self, config, run_dir: Path, resume: bool = False, progress: bool = True, name: str | None = None):
        self.folder = RunFolder(run_dir, config, resume=resume, name=name)
        self.config, self.run_dir, self.name = self.folder.config, self.folder.path, self.folder.name
        self.resume, self.progress = resume, progress
        self.metrics = self.folder.metrics
        self.best = self.initial_best()
        self.prefill = None
        self.clock = RunClock()

    # ------------------------------------------------------------------ the learner's pieces
    def initial_best(self) -> dict:
        return {"success_rate": -1.0}

    def is_better(self, row: dict) -> bool:
        return float(row["success_rate"]) > float(self.best["success_rate"])

    def make_evaluator(self) -> None:
        """Build what ``evaluate_policy`` needs (held-out env, goals or seeds)."""
        raise NotImplementedError

    def evaluate_policy(self) -> dict:
        """The metrics of one evaluation of ``self.model`` (``success_rate`` at least)."""
        raise NotImplementedError

    def close_evaluator(self) -> None:
        pass

    def env_record(self) -> dict:
        """What a checkpoint records about the env it was trained on (id, arguments, action scaling)."""
        return {"env_id": self.config.env_id, "env_kwargs": self.config.env_arguments()}

    def provenance(self, extra: dict | None = None) -> dict:
        return {**self.env_record(), "config": self.config.to_dict(), "seed": self.config.seed, **code_version(),
                **(extra or {})}

    def wrap_env(self, env):
        """The rollout envs as the learner's model sees them (the recording below sees the env's own actions)."""
        return env

    def save_policy(self, path: Path) -> None:
        """Write the policy the run has now (``best_model.zip``, ``model.zip``): SB3's zip without the buffer."""
        self.model.save(path, exclude=["replay_buffer"])

    def build_model(self, env):
        """A new model of ``algorithm_class`` with ``sac_arguments`` (and the learner's policy and buffer)."""
        raise NotImplementedError

    def prepare_new_run(self) -> None:
        """Checks before a new run's folder is written (a bad input leaves no folder behind)."""

    def prepare_data(self) -> None:
        """After the run's files exist (new or resumed), before the model: data the model is built with."""

    def start_new_model(self) -> None:
        """After a new run's model is built (e.g. initial weights)."""

    def use_datasets(self, new_run: bool) -> None:
        """Learn from the config's datasets (pre-fill, demonstrations); resumed runs re-read demonstrations."""

    def summary_extra(self) -> dict:
        return {}

    # ------------------------------------------------------------------ set-up
    def setup(self):
        configure_torch(self.config.torch_threads)
        if not self.resume:
            self.prepare_new_run()
            self.folder.write_run_files({"learner": self.learner_name,
                                         "training_loop": lag_record(self.config.overlap)})
        self.prepare_data()
        self.env = self.wrap_env(make_training_vec_env(self.config, self.folder.dataset(self.dataset_description)))
        self.make_evaluator()
        state = None
        latest = ckpt.latest_checkpoint(self.run_dir) if self.resume else None
        if self.resume and latest is None:
            raise ConfigError(f"cannot resume: {self.run_dir} has no complete checkpoint yet; start it anew "
                              "(delete the folder or pass another --out)")
        self.model = self.build_model(self.env)
        # a logger without outputs: learn() would otherwise configure one in a new SB3-<time> temp folder
        self.model.set_logger(Logger(folder=None, output_formats=[]))
        if self.config.overlap:  # FastSAC's overlapped learn (hingelab.learners.sac.overlap)
            self.model.overlap = True
        if latest is not None:
            state = ckpt.load_checkpoint(latest, self.model)  # weights, counters, buffer: nothing unpickled
        else:
            self.start_new_model()
        setattr(self.model, PROVENANCE_ATTRIBUTE, self.provenance())
        if state is not None:
            self.clock = RunClock(state["elapsed_s"])
            self.best = state["best"]
            self.next_eval, self.next_checkpoint = state["next_eval"], state["next_checkpoint"]
            set_episode_counts(self.env, state["episode_counts"])
            self.folder.drop_rollouts_after(covered_episodes(state))
            self.metrics.truncate_after(self.model.num_timesteps)
            self.mid_episode = state.get("mid_episode", False)
            if state.get("pending_updates"):  # an overlapped run's updates of its last step, run in the next one
                self.model.pending_updates = state["pending_updates"]
            self._state_rng = (state["rng"], state["action_space_rng"])
        else:
            self.next_eval, self.next_checkpoint = 0, self.config.checkpoint_every
            self.mid_episode = False
            self._state_rng = None

        with corrupt_policy(self.config.on_corrupt):  # the --from datasets' unreadable files (recorded in config)
            self.use_datasets(new_run=state is None)
        return self

    # ------------------------------------------------------------------ what the callbacks call
    def evaluate_now(self, env_steps: int, extra: dict) -> dict:
        row = {"env_steps": env_steps, "seed": self.config.seed, **self.evaluate_policy(), **extra}
        self.metrics.append(row)
        if self.is_better(row):
            self.best = {**{k: row[k] for k in self.initial_best()}, "env_steps": env_steps}
            setattr(self.model, PROVENANCE_ATTRIBUTE, self.provenance({"evaluation": row}))
            self.save_policy(self.run_dir / "best_model.zip")
        return row

    def checkpoint_now(self, mid_episode: bool) -> Path:
        counts = episode_counts(self.env)
        if not mid_episode:
            # the envs have already reset into their next episodes; on resume they reset into them again
            counts = [c - 1 for c in counts]
        schedules = {k: v for cb in self.callbacks.callbacks if hasattr(cb, "state_dict")
                     for k, v in cb.state_dict().items()}
        # the rollouts this checkpoint covers: every env's finished episodes (each env has one under way)
        finished = [c - 1 for c in episode_counts(self.env)]
        state = {"elapsed_s": self.clock.elapsed(), "best": self.best, **schedules, "episode_counts": counts,
                 "finished_episodes": finished,
                 "mid_episode": mid_episode, "pending_updates": getattr(self.model, "pending_updates", 0),
                 # random actions before learning_starts come from the action space's own generator
                 "action_space_rng": self.model.action_space.np_random.bit_generator.state}
        return ckpt.save_checkpoint(self.run_dir, self.model, state, keep=self.config.keep_checkpoints)

    # ------------------------------------------------------------------ training
    def train(self) -> dict:
        patience = CHECKPOINT_PATIENCE_EPISODES * self.config.max_episode_steps * self.config.n_envs
        self.callbacks = run_callbacks(
            self.clock, self.evaluate_now, self.checkpoint_now, eval_every=self.config.eval_every,
            checkpoint_every=self.config.checkpoint_every, patience=patience, total_steps=self.config.steps,
            desc=f"{self.label} {self.name}", progress=self.progress, next_eval=self.next_eval,
            next_checkpoint=self.next_checkpoint, mid_episode=self.mid_episode,
            last_row=(self.metrics.rows() or [{}])[-1] if self.resume else None)
        if self._state_rng is not None:  # last, after everything that seeds on load
            resume_state.restore_rng_states(self._state_rng[0])
            self.model.action_space.np_random.bit_generator.state = self._state_rng[1]
        remaining = self.config.steps - self.model.num_timesteps
        self.model.learn(total_timesteps=max(remaining, 0), callback=self.callbacks, reset_num_timesteps=False,
                         log_interval=None)
        return self.finish(self.clock.elapsed())

    def finish(self, elapsed_s: float) -> dict:
        setattr(self.model, PROVENANCE_ATTRIBUTE, self.provenance({"final_env_steps": self.model.num_timesteps}))
        self.save_policy(self.run_dir / "model.zip")
        rows = self.metrics.rows()
        self.env.close()
        self.close_evaluator()
        return {"run_dir": str(self.run_dir), "env_steps": self.model.num_timesteps, "updates": self.model._n_updates,
                "wall_time_s": elapsed_s, "last_evaluation": rows[-1] if rows else {}, "best": self.best,
                "prefill": None if self.prefill is None else self.prefill.__dict__ | {
                    "transitions_per_s": self.prefill.transitions_per_s}, **self.summary_extra()}


__all__ = ["SACRun", "algorithm_class", "sac_arguments", "PROVENANCE_ATTRIBUTE"]
