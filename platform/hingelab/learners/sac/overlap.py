"""Collection overlapped with learning: the gradient updates run while the env workers compute a step.

stable-baselines3's off-policy loop is serial: ``collect_rollouts`` acts and steps the envs, then
``learn`` calls ``train(gradient_steps)``. With env processes (``PinnedVecEnv``, SB3's
``SubprocVecEnv``) the learner waits idle while a worker simulates. ``OverlappedLearning.learn``
(on when ``overlap`` is True) keeps SB3's loop and moves the updates into that wait; per env step:

1. the policy picks ``a_t`` from the learner's current weights (``_sample_action``, unchanged);
2. ``env.step_async(a_t)`` sends it to the workers;
3. the updates due for the steps stored so far run (``pending_updates``: the ``gradient_steps``
   of the previous rollout, counted as SB3 counts them: after ``learning_starts``, every
   ``train_freq``);
4. ``env.step_wait()``, then SB3 stores transition ``t`` and calls the callbacks as before.

The bounds, recorded in each run's config.json (``lag_record``):

* policy lag 0 updates: the acting policy is the learner's own weights, never a copy, and no
  update is running while it acts;
* buffer lag 1 env step: an update samples a buffer that holds every stored transition, i.e.
  all but the ``n_envs`` transitions of the step in flight. Against the serial loop this is the
  one difference: the updates of step ``t`` run after ``a_{t+1}`` is chosen, not before.

The number of updates, their batches' buffer contents, SB3's counters, ``learning_starts``,
``train_freq``/``gradient_steps`` and the callbacks are SB3's. Pending updates are state: a
checkpoint records ``pending_updates`` (``SACRun.checkpoint_now``) and the resumed run runs them
during its first step, as the uninterrupted run did; ``learn`` runs what is left before
``on_training_end``, so the final model has every update. A finished run extended with a larger
``--steps`` continues from that flushed state, so it is not the same as one run to the larger
budget (a run resumed from any checkpoint before its end is).

With envs in this process (``DummyVecEnv``) ``step_async`` only stores the actions: the order
of the work is the same, nothing overlaps. ``hingelab.training.envs.make_training_vec_env`` gives
an overlapped run env processes even for one env.
"""

from __future__ import annotations

from typing import Any, Callable

from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

#: the buffer an update samples lacks at most the transitions of this many env steps (the step in flight)
BUFFER_LAG_ENV_STEPS = 1
#: updates between the weights the learner has and the weights the policy acts with
POLICY_LAG_UPDATES = 0


def lag_record(overlap: bool) -> dict:
    """The loop's lag bounds as a run's config.json records them (the serial loop: both 0)."""
    return {"overlap": bool(overlap), "buffer_lag_env_steps": BUFFER_LAG_ENV_STEPS if overlap else 0,
            "policy_lag_updates": POLICY_LAG_UPDATES}


class UpdatesDuringStep(VecEnvWrapper):
    """The envs, with ``run_updates()`` called between sending a step (``step_async``) and waiting
    for its result (``step_wait``)."""

    def __init__(self, venv: VecEnv, run_updates: Callable[[], None]):
        super().__init__(venv)
        self.run_updates = run_updates

    def reset(self):
        return self.venv.reset()

    def step_async(self, actions) -> None:
        self.venv.step_async(actions)
        self.run_updates()

    def step_wait(self):
        return self.venv.step_wait()


class OverlappedLearning:
    """A mixin for an SB3 off-policy algorithm (before it in the bases): ``learn`` with the updates
    overlapped with the env steps when ``overlap`` is True, SB3's own ``learn`` otherwise."""

    overlap: bool = False
    pending_updates: int = 0  # gradient steps due for stored transitions, not run yet

    def _excluded_save_params(self) -> list[str]:
        # the run's config says whether it overlaps; a checkpoint's state.json holds pending_updates
        return [*super()._excluded_save_params(), "overlap", "pending_updates"]

    def run_pending_updates(self) -> None:
        """The updates due so far (``train``), then the policy back in acting mode."""
        updates, self.pending_updates = self.pending_updates, 0
        if updates > 0:
            self.train(batch_size=self.batch_size, gradient_steps=updates)
            self.policy.set_training_mode(False)

    def learn(self, total_timesteps: int, callback: Any = None, log_interval: int = 4, tb_log_name: str = "run",
              reset_num_timesteps: bool = True, progress_bar: bool = False):
        if not self.overlap:
            return super().learn(total_timesteps, callback=callback, log_interval=log_interval,
                                 tb_log_name=tb_log_name, reset_num_timesteps=reset_num_timesteps,
                                 progress_bar=progress_bar)
        # SB3's OffPolicyAlgorithm.learn, but train() runs inside the next env step (UpdatesDuringStep)
        total_timesteps, callback = self._setup_learn(total_timesteps, callback, reset_num_timesteps,
                                                      tb_log_name, progress_bar)
        callback.on_training_start(locals(), globals())
        env = UpdatesDuringStep(self.env, self.run_pending_updates)
        while self.num_timesteps < total_timesteps:
            rollout = self.collect_rollouts(
                env, train_freq=self.train_freq, action_noise=self.action_noise,
                callback=callback, learning_starts=self.learning_starts,
                replay_buffer=self.replay_buffer, log_interval=log_interval)
            if not rollout.continue_training:
                break
            if self.num_timesteps > 0 and self.num_timesteps > self.learning_starts:
                gradient_steps = self.gradient_steps if self.gradient_steps >= 0 else rollout.episode_timesteps
                self.pending_updates += max(gradient_steps, 0)
        self.run_pending_updates()  # the final model has every update of the run
        callback.on_training_end()
        return self


__all__ = ["OverlappedLearning", "UpdatesDuringStep", "lag_record", "BUFFER_LAG_ENV_STEPS", "POLICY_LAG_UPDATES"]
