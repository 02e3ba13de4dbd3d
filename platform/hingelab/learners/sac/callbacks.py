"""The callbacks of a SAC run, composed in stable-baselines3's ``CallbackList``.

``run_callbacks`` puts them in this order (SB3 calls them in list order):

* ``TrainingStats``: wall time over the run's sessions, env steps per second, the last
  losses and the training episodes' success rate: the extra columns of a metrics row;
* ``EvaluationCallback``: every ``every`` env steps, ``evaluate(env_steps, extras)``;
* ``CheckpointCallback``: every ``every`` env steps, ``save(mid_episode)``, where all envs have
  just finished an episode (or, after ``patience`` more steps, mid-episode);
* ``ProgressCallback``: the bar, with the last evaluation's and the rollouts' success.

None of them holds the run: each gets the functions it calls. SB3's loop is
``collect_rollouts`` (``on_rollout_start``, then ``on_step`` after every vectorized env
step) and then the gradient updates of that rollout. Evaluations and checkpoints happen in
``on_rollout_start``, i.e. after the previous rollout's updates, so a checkpoint holds a
model that has had every update for the steps it has seen (with ``--overlap``, all but the last
step's, which run during the next step: ``hingelab.learners.sac.overlap``); ``on_training_end``
(after the last updates) evaluates and checkpoints the final step.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from tqdm import tqdm

# a checkpoint waits for all envs to finish an episode together, but not forever (drops
# desynchronize the envs): after this many episode lengths it is taken mid-episode
CHECKPOINT_PATIENCE_EPISODES = 3


class RunClock:
    """Wall time of a run over all its sessions (``elapsed_before``: the sessions before this one)."""

    def __init__(self, elapsed_before: float = 0.0):
        self.elapsed_before = elapsed_before
        self.start = time.perf_counter()

    def elapsed(self) -> float:
        return self.elapsed_before + time.perf_counter() - self.start


class TrainingStats(BaseCallback):
    """Rates, losses and the rollouts' success: ``extras()`` is the tail of a metrics row."""

    def __init__(self, clock: RunClock):
        super().__init__(verbose=0)
        self.clock = clock
        self.steps_at_start = 0
        self.learning_clock: tuple[int, float] | None = None  # (steps, time) when updates began: the rate users feel

    def _on_training_start(self) -> None:
        self.steps_at_start = self.model.num_timesteps

    def _on_rollout_start(self) -> None:
        if self.learning_clock is None and self.model.num_timesteps >= self.model.learning_starts:
            self.learning_clock = (self.model.num_timesteps, time.perf_counter())

    def _on_step(self) -> bool:
        return True

    def rollout_success_rate(self) -> float:
        # SB3 keeps info["is_success"] of each finished training episode: the env's one verdict
        buf = self.model.ep_success_buffer
        return float(np.mean(buf)) if len(buf) else float("nan")

    def extras(self) -> dict:
        seconds = time.perf_counter() - self.clock.start
        logged = self.model.logger.name_to_value if self.model.logger is not None else {}
        losses = {name: float(logged.get(f"train/{name}", float("nan")))
                  for name in ("critic_loss", "actor_loss", "ent_coef")}
        learning_rate = float("nan")
        if self.learning_clock is not None and self.model.num_timesteps > self.learning_clock[0]:
            learning_rate = ((self.model.num_timesteps - self.learning_clock[0])
                             / max(time.perf_counter() - self.learning_clock[1], 1e-9))
        return {**losses, "updates": self.model._n_updates, "wall_time_s": round(self.clock.elapsed(), 2),
                "rollout_success_rate": self.rollout_success_rate(),
                "env_steps_per_s": (self.model.num_timesteps - self.steps_at_start) / max(seconds, 1e-9),
                "env_steps_per_s_learning": learning_rate}


class EvaluationCallback(BaseCallback):
    """``evaluate(env_steps, extras) -> row`` at every multiple of ``every`` env steps and at the end."""

    def __init__(self, evaluate: Callable[[int, dict], dict], every: int, extras: Callable[[], dict],
                 next_eval: int = 0, last_row: dict | None = None):
        """``last_row``: a resumed run's last metrics row (its end is not evaluated twice)."""
        super().__init__(verbose=0)
        self.evaluate, self.every, self.extras = evaluate, every, extras
        self.next_eval = next_eval
        self.last_row: dict = dict(last_row or {})

    def state_dict(self) -> dict:
        return {"next_eval": self.next_eval}

    def _evaluate(self, steps: int) -> None:
        self.last_row = self.evaluate(steps, self.extras())
        self.next_eval = (steps // self.every + 1) * self.every

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps >= self.next_eval:
            self._evaluate(self.model.num_timesteps)

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        steps = self.model.num_timesteps
        if not self.last_row or int(self.last_row["env_steps"]) != steps:
            self._evaluate(steps)


class CheckpointCallback(BaseCallback):
    """``save(mid_episode)`` at every multiple of ``every`` env steps, where every env has just
    finished an episode (``mid_episode`` False: their next episodes are fully determined), or
    ``patience`` steps later mid-episode; and at the end."""

    def __init__(self, save: Callable[[bool], object], every: int, patience: int, next_checkpoint: int,
                 mid_episode: bool = False):
        super().__init__(verbose=0)
        self.save, self.every, self.patience = save, every, patience
        self.next_checkpoint = next_checkpoint
        self.all_done = not mid_episode  # start of learn: envs are fresh

    def state_dict(self) -> dict:
        return {"next_checkpoint": self.next_checkpoint}

    def _on_rollout_start(self) -> None:
        steps = self.model.num_timesteps
        if steps >= self.next_checkpoint and (self.all_done or steps >= self.next_checkpoint + self.patience):
            self.next_checkpoint = (steps // self.every + 1) * self.every
            self.save(not self.all_done)

    def _on_step(self) -> bool:
        dones = self.locals.get("dones")
        self.all_done = bool(np.all(dones)) if dones is not None else False
        return True

    def _on_training_end(self) -> None:
        self.save(not self.all_done)


class ProgressCallback(BaseCallback):
    """A tqdm bar over the run's env steps; ``status()`` gives its postfix."""

    def __init__(self, total: int, desc: str, status: Callable[[], dict], enabled: bool = True):
        super().__init__(verbose=0)
        self.total, self.desc, self.status, self.enabled = total, desc, status, enabled
        self.bar = None

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, initial=self.model.num_timesteps, unit="step", desc=self.desc,
                        disable=not self.enabled, smoothing=0.05)

    def _on_step(self) -> bool:
        self.bar.n = self.model.num_timesteps
        if self.n_calls % 50 == 0:
            self.bar.set_postfix(self.status(), refresh=False)
            self.bar.refresh()
        return True

    def _on_training_end(self) -> None:
        self.bar.n = self.model.num_timesteps
        self.bar.set_postfix(self.status(), refresh=False)
        self.bar.close()


def run_callbacks(clock: RunClock, evaluate: Callable[[int, dict], dict], save: Callable[[bool], object], *,
                  eval_every: int, checkpoint_every: int, patience: int, total_steps: int, desc: str,
                  progress: bool = True, next_eval: int = 0, next_checkpoint: int = 0,
                  mid_episode: bool = False, last_row: dict | None = None) -> CallbackList:
    """The four callbacks of a run, wired together, in their order."""
    stats = TrainingStats(clock)
    evaluation = EvaluationCallback(evaluate, eval_every, stats.extras, next_eval=next_eval, last_row=last_row)
    checkpoint = CheckpointCallback(save, checkpoint_every, patience, next_checkpoint, mid_episode=mid_episode)

    def status() -> dict:
        return {"eval_success": f"{float(evaluation.last_row.get('success_rate', float('nan'))):.2f}",
                "rollout_success": f"{stats.rollout_success_rate():.2f}"}

    return CallbackList([stats, evaluation, checkpoint, ProgressCallback(total_steps, desc, status, progress)])


__all__ = ["RunClock", "TrainingStats", "EvaluationCallback", "CheckpointCallback", "ProgressCallback",
           "run_callbacks", "CHECKPOINT_PATIENCE_EPISODES"]
