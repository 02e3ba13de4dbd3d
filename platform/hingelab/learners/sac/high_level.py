"""SAC on ToolPick-v0 (``train high``: a frozen low level inside) and on the flat baseline
ToolPickFlat-v0 (``train flat``), on the SAC training core (``hingelab.learners.sac.run``).

* ``PickRun``: what both share: held-out evaluations (``hingelab.training.pick_run_parts``) and what
  checkpoints record (the env's arguments, its action scaling, the encoder's fingerprint and the low
  level's sha256: ``hingelab.policies.high_level`` refuses the policy beside another low level).
* ``HighLevelRun``: the privileged prior (``PriorData``: ``--from`` or generated into ``RUNDIR/prior``),
  in a ``DemoShareReplayBuffer`` (``--demo-share`` of every batch) or, with ``--demo-share 0``, through
  the buffer's own ``add`` into the ring buffer (the paper's plain pre-fill); with
  ``--bc-weight``/``--bc-pretrain`` also in ``DemoSAC``'s BC term.
* ``FlatRun``: no low level and no demos.
"""

from __future__ import annotations

from pathlib import Path

from stable_baselines3.common.logger import Logger

from hingelab.envs.tool_pick_flat import FINGER_SCALE
from hingelab.learners.sac.demo_sac import Demonstrations
from hingelab.learners.sac.high_level_config import FlatTrainConfig, HighLevelTrainConfig
from hingelab.learners.sac.run import SACRun, algorithm_class, sac_arguments
from hingelab.policies.high_level import training_context
from hingelab.tasks import MAX_SPEED, Z_SCALE
from hingelab.training.high_level_demos import DemoShareReplayBuffer, fill_high_level_buffer
from hingelab.training.pick_run_parts import PickEvaluation, PriorData, check_pick_inputs


class PickRun(SACRun):
    """A SAC run on ToolPick-v0 or ToolPickFlat-v0: its evaluation and its checkpoints' records."""

    def prepare_new_run(self) -> None:
        check_pick_inputs(self.config)

    def make_evaluator(self) -> None:
        self.evaluation = PickEvaluation(self.config)

    def evaluate_policy(self) -> dict:
        return self.evaluation(self.model)

    def is_better(self, row: dict) -> bool:
        return PickEvaluation.is_better(row, self.best)

    def initial_best(self) -> dict:
        return PickEvaluation.initial_best()

    def close_evaluator(self) -> None:
        self.evaluation.close()

    def prior_record(self) -> dict | None:
        return None

    def provenance(self, extra: dict | None = None) -> dict:
        if not hasattr(self, "_context"):  # hashes the low level's file: once per run, not per best model
            self._context = training_context(self.config.low_level)
        return super().provenance({**self._context, "prior": self.prior_record(), **(extra or {})})

    def summary_extra(self) -> dict:
        return {"prior": None, "eval_episodes": self.config.eval_episodes}

    def build_model(self, env):
        return algorithm_class(self.config)("MlpPolicy", env, **sac_arguments(self.config))


class HighLevelRun(PickRun):
    label = "train high"
    dataset_description = "every training rollout of a hingelab train high run"

    def prepare_data(self) -> None:
        self.prior = None
        if not self.config.prior:
            return
        self.prior = PriorData(self.config, self.run_dir, self.name, self.progress)
        self.prior.load()
        if not self.resume:  # config.json says which datasets (and sources) filled the buffer
            self.folder.record_run_fact("prior", self.prior.info)

    @property
    def demos(self):
        return None if self.prior is None else self.prior.demos

    def build_model(self, env):
        kwargs = sac_arguments(self.config)
        if self.demos is not None and self.config.demo_share > 0:
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
            method = "add" if self.config.n_envs == 1 else "bulk"
            fill_high_level_buffer(self.model.replay_buffer, self.demos, method=method)

    def use_datasets(self, new_run: bool) -> None:
        if self.demos is None:
            return
        if self.config.learns_from_demonstrations:
            self.model.set_demonstrations(Demonstrations.from_transitions(self.demos))
            if new_run and self.config.bc_pretrain_updates:
                self.model.pretrain_actor(self.config.bc_pretrain_updates, self.config.batch_size,
                                          fit_std=self.config.bc_pretrain_std)
        if new_run and self.config.demo_offline_updates:
            self._warm_up_on_demos(self.config.demo_offline_updates)

    def _warm_up_on_demos(self, updates: int) -> None:
        """SAC updates from the demos alone (the ring buffer is still empty, or holds only them)."""
        self.model.set_logger(Logger(folder=None, output_formats=[]))  # no SB3-<time> temp folder
        # SB3's own set-up of learn(): resets the envs once, which learn() then does not do again
        self.model._setup_learn(0, callback=None, reset_num_timesteps=False)
        self.model.train(gradient_steps=updates, batch_size=self.config.batch_size)

    def env_record(self) -> dict:
        return {**super().env_record(), "action_scale": {"z_goal": Z_SCALE, "hand_velocity_m_s": MAX_SPEED}}

    def prior_record(self) -> dict | None:
        if self.prior is None:
            return None
        return {**self.prior.info, "demo_share": self.config.demo_share, "demo_actions": self.prior.modes,
                "demo_lookahead": self.config.demo_lookahead}

    def summary_extra(self) -> dict:
        return {"prior": None if self.prior is None else self.prior.info, "eval_episodes": self.config.eval_episodes}


class FlatRun(PickRun):
    label = "train flat"
    dataset_description = "every training rollout of a hingelab train flat run"

    def env_record(self) -> dict:
        return {**super().env_record(), "action_scale": {"fingers_rad": FINGER_SCALE, "hand_velocity_m_s": MAX_SPEED}}


def train_high(config: HighLevelTrainConfig, run_dir, resume: bool = False, progress: bool = True,
               name: str | None = None) -> dict:
    """Train (or resume) a SAC run on ToolPick-v0 (with a ``FlatTrainConfig``: on ToolPickFlat-v0); a summary."""
    cls = FlatRun if isinstance(config, FlatTrainConfig) else HighLevelRun
    return cls(config, Path(run_dir), resume=resume, progress=progress, name=name).setup().train()
