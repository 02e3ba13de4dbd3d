"""The SB3 callback of ``hingelab train low``: progress bar, evaluations, checkpoints.

SB3's loop is: ``collect_rollouts`` (``on_rollout_start``, then ``on_step`` after every
vectorized env step) and then the gradient updates of that rollout. Evaluations and
checkpoints happen in ``on_rollout_start``, i.e. after the previous rollout's updates,
so a checkpoint holds a model that has had every update for the steps it has seen.
"""

from __future__ import annotations

import time

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

# a checkpoint waits for all envs to finish an episode together, but not forever (drops
# desynchronize the envs): after this many episode lengths it is taken mid-episode
CHECKPOINT_PATIENCE_EPISODES = 3


class TrainingCallback(BaseCallback):
    def __init__(self, run, progress: bool = True):
        super().__init__(verbose=0)
        self.run = run
        self.progress = progress
        self.all_done = not run.mid_episode  # start of learn: envs are fresh
        self.start = time.perf_counter()
        self.bar = None
        self.last_row: dict = {}
        self.steps_at_start = 0
        self.learning_clock = None  # (steps, time) when updates began: the rate users feel

    def elapsed(self) -> float:
        return self.run.elapsed_before + time.perf_counter() - self.start

    def _on_training_start(self) -> None:
        self.steps_at_start = self.model.num_timesteps
        self.bar = tqdm(total=self.run.config.steps, initial=self.model.num_timesteps, unit="step",
                        desc=f"train low {self.run.name}", disable=not self.progress, smoothing=0.05)

    def _rollout_rate(self) -> float:
        # SB3 keeps info["is_success"] of each finished training episode: the env's one verdict
        # (ToolShape-v0: settled over the last 0.5 s), as the evaluations' success_rate and the datasets count it
        buf = self.model.ep_success_buffer
        return float(np.mean(buf)) if len(buf) else float("nan")

    def _extra(self) -> dict:
        seconds = time.perf_counter() - self.start
        logged = self.model.logger.name_to_value if self.model.logger is not None else {}
        losses = {name: float(logged.get(f"train/{name}", float("nan")))
                  for name in ("critic_loss", "actor_loss", "ent_coef")}
        learning_rate = float("nan")
        if self.learning_clock is not None and self.model.num_timesteps > self.learning_clock[0]:
            learning_rate = ((self.model.num_timesteps - self.learning_clock[0])
                             / max(time.perf_counter() - self.learning_clock[1], 1e-9))
        return {**losses, "updates": self.model._n_updates, "wall_time_s": round(self.elapsed(), 2),
                "rollout_success_rate": self._rollout_rate(),
                "env_steps_per_s": (self.model.num_timesteps - self.steps_at_start) / max(seconds, 1e-9),
                "env_steps_per_s_learning": learning_rate}

    def _maybe_evaluate_and_checkpoint(self) -> None:
        run, steps = self.run, self.model.num_timesteps
        if steps >= run.next_eval:
            self.last_row = run.evaluate_now(steps, self._extra())
            run.next_eval = (steps // run.config.eval_every + 1) * run.config.eval_every
        patience = CHECKPOINT_PATIENCE_EPISODES * run.config.max_episode_steps * run.config.n_envs
        if steps >= run.next_checkpoint and (self.all_done or steps >= run.next_checkpoint + patience):
            run.next_checkpoint = (steps // run.config.checkpoint_every + 1) * run.config.checkpoint_every
            run.checkpoint_now(self.elapsed(), mid_episode=not self.all_done)

    def _on_rollout_start(self) -> None:
        if self.learning_clock is None and self.model.num_timesteps >= self.model.learning_starts:
            self.learning_clock = (self.model.num_timesteps, time.perf_counter())
        self._maybe_evaluate_and_checkpoint()

    def _on_step(self) -> bool:
        dones = self.locals.get("dones")
        self.all_done = bool(np.all(dones)) if dones is not None else False
        if self.bar is not None:
            self.bar.n = self.model.num_timesteps
            if self.n_calls % 50 == 0:
                self.bar.set_postfix(eval_success=f"{self.last_row.get('success_rate', float('nan')):.2f}",
                                     rollout_success=f"{self._rollout_rate():.2f}", refresh=False)
                self.bar.refresh()
        return True

    def finish(self) -> None:
        """After ``learn``: the last updates are done; final evaluation and checkpoint."""
        run, steps = self.run, self.model.num_timesteps
        if not self.last_row or int(self.last_row["env_steps"]) != steps:
            self.last_row = run.evaluate_now(steps, self._extra())
            run.next_eval = (steps // run.config.eval_every + 1) * run.config.eval_every
        run.checkpoint_now(self.elapsed(), mid_episode=not self.all_done)
        if self.bar is not None:
            self.bar.n = steps
            self.bar.close()
