"""``hingelab train high --learner residual-sac``: SAC of a bounded residual over a frozen phase clone.

The run is ``train high``'s (``hingelab.learners.sac.high_level.PickRun``: run folder, recorded rollouts,
held-out evaluations, checkpoints, exact resume) with the residual's pieces:

* the base (``--base``): the shipped phase clone, a phase-clone checkpoint, or one the run fits first on
  its privileged prior (saved as ``RUNDIR/base.zip``; a resumed run loads it). A base that learned beside
  another low level or encoder is refused, as ``eval high`` refuses it;
* the envs as the residual sees them (``ResidualVecEnv``);
* the prior's demos in the residual's terms (``residual_transitions``), ``--demo-share`` of every batch;
* ``ResidualSAC`` on ``ResidualSACPolicy`` (``algorithm``, ``networks``);
* evaluations and ``best_model.zip`` / ``model.zip`` of the residual policy (``policies.residual``):
  ``hingelab eval high RUNDIR/model.zip`` runs it.
"""

from __future__ import annotations

import copy
import hashlib
import io
from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.logger import Logger

from hingelab.errors import ConfigError
from hingelab.learners.phase_clone.fit import PhaseDemos, fit_phase_clone_members
from hingelab.learners.residual.algorithm import ResidualSAC
from hingelab.learners.residual.config import ResidualSACConfig
from hingelab.learners.residual.networks import ResidualSACPolicy, actor_state_for_policy
from hingelab.learners.residual.vec_env import ResidualVecEnv
from hingelab.learners.sac.high_level import PickRun
from hingelab.learners.sac.run import PROVENANCE_ATTRIBUTE, sac_arguments
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL, check_context, trained_tool_position, training_context
from hingelab.policies.phase_clone import PhaseClone
from hingelab.policies.residual import ResidualPolicy, load_base
from hingelab.tasks import MAX_SPEED, Z_SCALE, observation_dim
from hingelab.training.high_level_demos import DemoShareReplayBuffer
from hingelab.training.pick_run_parts import PriorData

BASE_FILE = "base.zip"
ACTION_NAMES = ("z_goal_0", "z_goal_1", "velocity_x", "velocity_y", "velocity_z")


def residual_transitions(demos, policy: ResidualPolicy):
    """The demos as the residual learner's transitions: observations as its inputs (the base's memory run
    along each demo episode from its start, as at run time), actions as the residual that executes the
    demonstrated action, ``(a_demo - a_base) / scale`` (not clipped: the critic values the executed action,
    ``clip(a_base + scale * residual)``, which is then the demonstrated one)."""
    n = len(demos)
    obs = np.asarray(demos.observations, np.float32)
    next_obs = np.asarray(demos.next_observations, np.float32)
    x = np.empty((n, policy.inputs.dim), np.float32)
    x_next = np.empty_like(x)
    residual = np.empty((n, 5), np.float32)
    episodes = [np.flatnonzero(demos.episode_index == e) for e in np.unique(demos.episode_index)]
    memory = np.zeros((len(episodes), 2), np.int64)
    for t in range(max(len(rows) for rows in episodes)):
        active = np.array([i for i, rows in enumerate(episodes) if len(rows) > t])
        rows = np.array([episodes[i][t] for i in active])
        inputs, base_action, next_memory = policy.step(obs[rows], memory[active])
        x[rows] = inputs
        residual[rows] = (np.asarray(demos.actions, np.float32)[rows] - base_action) / policy.scale
        x_next[rows], _, _ = policy.step(next_obs[rows], next_memory)
        memory[active] = next_memory
    out = copy.copy(demos)
    out.observations, out.next_observations, out.actions = x, x_next, residual
    return out


class ResidualRun(PickRun):
    label = "train high (residual)"
    learner_name = "residual-sac"
    dataset_description = "every training rollout of a hingelab train high --learner residual-sac run"

    # ------------------------------------------------------------------ data: the prior, the base, the demos
    def prepare_data(self) -> None:
        c = self.config
        self.prior = None
        if c.prior:
            self.prior = PriorData(c, self.run_dir, self.name, self.progress)
            self.prior.load()
            if not self.resume:
                self.folder.record_run_fact("prior", self.prior.info)
        self.base_path, base_bytes = self._base_bytes()
        base = load_base(io.BytesIO(base_bytes), where=str(self.base_path))
        expected = observation_dim(bool(c.env_kwargs.get("observe_extent", False)))
        if base.observation_dim != expected:
            raise ConfigError(f"the base {self.base_path} takes {base.observation_dim}-D observations, the run's "
                              f"ToolPick-v0 gives {expected}-D ones: set observe_extent in --env-kwargs as the base "
                              "was trained")
        trained, here = trained_tool_position(base), str(c.env_kwargs.get("tool_position", "observed"))
        if trained != here:
            raise ConfigError(f"the base {self.base_path} was trained on the {trained} tool position, the run's "
                              f"ToolPick-v0 gives the {here} one: drop tool_position from --env-kwargs (the run "
                              "observes as its base) or give a base trained on it")
        check_context(base, self.base_path, c.low_level)
        self.policy = ResidualPolicy(base, None, c.residual_scale, base_bytes=base_bytes)
        self.demos = residual_transitions(self.prior.demos, self.policy) if c.uses_demos else None
        if not self.resume:
            self.folder.record_run_fact("base", {"path": str(self.base_path),
                                                 "sha256": _sha256(base_bytes), "nets": len(base.nets)})

    def _base_bytes(self) -> tuple[Path, bytes]:
        c = self.config
        if c.base == "fit":
            path = self.run_dir / BASE_FILE
            if not path.exists():  # a resumed run keeps the base it fitted
                self._fit_base(path)
            return path, path.read_bytes()
        path = SHIPPED_HIGH_LEVEL if c.base == "shipped" else Path(c.base)
        if not path.is_file():
            raise ConfigError(f"--base {c.base}: no file at {path}; give a phase-clone checkpoint, shipped or fit")
        load_base(path)  # a one-line error for a file that is not a phase clone
        return path, path.read_bytes()

    def _fit_base(self, path: Path) -> None:
        c = self.config
        demos = PhaseDemos.from_transitions(self.prior.demos, where=", ".join(self.prior.info["datasets"]))
        if self.progress:
            print(f"{self.label} {self.name}: fitting the base clone on {len(demos)} demo steps "
                  f"({c.clone_updates} updates)")
        nets, fit = fit_phase_clone_members(demos, 1, tuple(c.clone_net_arch), c.clone_updates, c.clone_batch_size,
                                            c.clone_learning_rate, c.seed, progress=self.progress)
        clone = PhaseClone(nets, {**self.env_record(), **training_context(c.low_level), "learner": "phase-clone",
                                  "fit": fit, "fitted_by": "train high --learner residual-sac --base fit"})
        clone.save(path)

    # ------------------------------------------------------------------ env and model
    def wrap_env(self, env):
        return ResidualVecEnv(env, self.policy)

    def build_model(self, env):
        c = self.config
        kwargs = sac_arguments(c)
        kwargs["policy_kwargs"].update(residual_scale=self.policy.scale.tolist(), log_std_max=c.log_std_max(),
                                       critic_layer_norm=c.critic_layer_norm, n_critics=c.critics)
        if c.exploration_floor:  # only then: the zips of runs without a floor stay as they were
            kwargs["policy_kwargs"]["log_std_min"] = c.log_std_min()
        kwargs.update(actor_start=c.actor_start, target_critics=c.target_critics, residual_penalty=c.residual_penalty,
                      choose_by_q=c.choose_by_q, actor_q=c.actor_q, actor_update=c.actor_update,
                      awr_temperature=c.awr_temperature)
        if self.demos is not None:
            kwargs.update(replay_buffer_class=DemoShareReplayBuffer,
                          replay_buffer_kwargs={"demos": self.demos, "demo_share": c.demo_share})
        model = ResidualSAC(ResidualSACPolicy, env, **kwargs)
        if self.demos is not None:
            model.replay_buffer_kwargs = {"demo_share": c.demo_share}  # the zip does not carry the demos
        return model

    def use_datasets(self, new_run: bool) -> None:
        """A new run with demos: ``--critic-pretrain`` critic-only updates on them before the first env step."""
        if not (new_run and self.demos is not None and self.config.critic_pretrain_updates):
            return
        self.model.set_logger(Logger(folder=None, output_formats=[]))  # no SB3-<time> temp folder
        # SB3's own set-up of learn(): resets the envs once, which learn() then does not do again
        self.model._setup_learn(0, callback=None, reset_num_timesteps=False)
        self.model.pretrain_critic(self.config.critic_pretrain_updates, self.config.batch_size)

    def current_policy(self) -> ResidualPolicy:
        actor = self.model.actor
        return ResidualPolicy(self.policy.base, lambda x: actor(x, deterministic=True), self.policy.scale,
                              getattr(self.model, PROVENANCE_ATTRIBUTE, {}), self.policy.base_bytes,
                              self.model.chooser() if self.config.choose_by_q else None)

    def evaluate_policy(self) -> dict:
        self.model.actor.set_training_mode(False)
        return {**self.evaluation(self.current_policy()), **self.residual_statistics()}

    def residual_statistics(self, rows: int = 2000) -> dict:
        """On the newest ``rows`` transitions of the ring buffer: the deterministic residual's mean |.| and mean
        (signed: a drift one way, e.g. the hand pushed down) per action dimension (action units, after the scale)
        and the critics' mean Q of the policy's action."""
        buffer = self.model.replay_buffer
        n = buffer.buffer_size if buffer.full else buffer.pos
        if n == 0:
            return {}
        newest = (buffer.pos - 1 - np.arange(min(rows, n))) % buffer.buffer_size
        obs = torch.as_tensor(buffer.observations[newest, 0])
        with torch.no_grad():
            residual = self.model.actor(obs, deterministic=True)
            q = self.model.critic.q_values(obs, residual).mean()
        size = (residual.abs().mean(0).numpy() * self.policy.scale).tolist()
        drift = (residual.mean(0).numpy() * self.policy.scale).tolist()
        return {**{f"residual_abs_{name}": round(v, 6) for name, v in zip(ACTION_NAMES, size)},
                **{f"residual_mean_{name}": round(v, 6) for name, v in zip(ACTION_NAMES, drift)},
                "q_policy_mean": float(q)}

    def save_policy(self, path: Path) -> None:
        critic = self.model.critic.policy_record() if self.config.choose_by_q else None
        self.current_policy().save(path, actor_state_for_policy(self.model.actor), tuple(self.config.net_arch), critic)

    # ------------------------------------------------------------------ records
    def env_record(self) -> dict:
        return {**super().env_record(), "action_scale": {"z_goal": Z_SCALE, "hand_velocity_m_s": MAX_SPEED}}

    def prior_record(self) -> dict | None:
        base = {"base": str(self.base_path), "base_sha256": _sha256(self.policy.base_bytes)}
        if self.prior is None:
            return base
        return {**self.prior.info, **base, "demo_share": self.config.demo_share if self.demos is not None else 0.0}

    def summary_extra(self) -> dict:
        return {"prior": None if self.prior is None else self.prior.info, "eval_episodes": self.config.eval_episodes,
                "base": str(self.base_path)}


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def train_residual(config: ResidualSACConfig, run_dir, resume: bool = False, progress: bool = True,
                   name: str | None = None) -> dict:
    """Train (or resume) a residual SAC run on ToolPick-v0; a summary dict."""
    return ResidualRun(config, Path(run_dir), resume=resume, progress=progress, name=name).setup().train()


__all__ = ["train_residual", "ResidualRun", "residual_transitions", "BASE_FILE"]
