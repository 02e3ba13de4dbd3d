"""``train_high`` and ``train_flat``: SAC on ToolPick-v0 (a frozen low level inside) and on the
flat baseline ToolPickFlat-v0, on the training core (``hingelab.learning.sac_run``); and the phase
clone (``--learner phase-clone``, ``PhaseCloneRun``) in the same run folder.

The high level's pieces:

* the privileged prior (``prepare_data``): privileged demos, from ``--from`` or generated into
  ``RUNDIR/prior`` (``high_level_prior``: ``--prior-source scripted`` or ``heuristic``,
  ``--prior-episodes``), turned into transitions of ToolPick-v0's spaces with the run's reward
  (``high_level_transitions``; the demo action is the recorded command, or the reached latent
  ``--demo-lookahead`` steps on, and the recorded hand velocity). They go into a
  ``DemoShareReplayBuffer`` (``--demo-share`` of every batch) or, with ``--demo-share 0``, through
  the buffer's own ``add`` into the ring buffer (the paper's plain pre-fill); with
  ``--bc-weight``/``--bc-pretrain`` also into ``DemoSAC``'s BC term. The choice is in the run's
  config.json.
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
from hingelab.learning.fast_sac import configure_torch
from hingelab.learning.high_level_config import FlatTrainConfig, HighLevelTrainConfig
from hingelab.learning.sac_run import SACRun, algorithm_class, sac_arguments

PRIOR_DIR = "prior"
EVAL_SEED = 77  # held-out evaluations during training: `hingelab eval high --seed 77`'s episodes


def summarize_pick(episodes) -> dict:
    """One metrics row of a ToolPick evaluation table (``high_level_eval.evaluate``): the pick table's
    rates (``pick_rates``, without the interval columns), the return, the length, the final distance."""
    from hingelab.analysis.pick_table import pick_rates

    rates = {k: v for k, v in pick_rates(episodes).items()
             if k in ("success_rate", "first_attempt_success_rate", "mean_attempts") or k.startswith("failures_")}
    return {**rates, "return": float(episodes["return"].mean()), "mean_length": float(episodes["length"].mean()),
            "final_object_target_distance_m": float(episodes["object_target_distance_m"].median())}


def prior_dataset_record(root, transitions, mode: str, skipped: list) -> dict:
    """What one --from dataset gave the demos: its source, episodes, transitions, actions, left-out episodes."""
    from hingelab.episodes.dataset import Dataset

    card = Dataset(root).card
    record = {"path": str(root), "source": card.source, "name": card.name, "transitions": len(transitions),
              "episodes": int(len(np.unique(transitions.episode_index))), "demo_actions": mode,
              "skipped": [{"episode": path, "reason": reason} for path, reason in skipped]}
    if "demo_action_recorded" in transitions.infos:  # real episodes: the rig's command or the reached action
        record["transitions_with_recorded_action"] = int(transitions.infos["demo_action_recorded"].sum())
    return record


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
                                  "(hingelab generate heuristic), a ToolPick-v0 recording or real episodes "
                                  "(hingelab datasets import-ros2), or drop --from to generate one")

    def prior_datasets(self) -> list[str]:
        """The demos' datasets: --from, or the prior the run generates (once; a resumed run reuses it)."""
        if self.config.from_datasets:
            return [str(p) for p in self.config.from_datasets]
        from hingelab.learning.high_level_prior import generate_prior, prior_parts

        root = self.run_dir / PRIOR_DIR
        roots = [root / folder for folder, *_ in prior_parts(self.config)]
        if not all((r / "dataset.json").exists() and any((r / "episodes").glob("*.mcap")) for r in roots):
            roots = generate_prior(root, self.config, name=f"{self.name}-prior", progress=self.progress)
        return [str(r) for r in roots]

    def demo_action_mode(self, root) -> str:
        """--demo-actions, or for auto: the recorded command of scripted demos, the reached latent otherwise."""
        if self.config.demo_actions != "auto":
            return self.config.demo_actions
        from hingelab.episodes.dataset import Dataset

        card = Dataset(root).card
        if card.source == "real":  # the rig's own command where it recorded one (real_prefill)
            return "recorded"
        policy = (card.config or {}).get("policy")
        return "recorded" if policy in ("scripted", "scripted-feedback") else "reached"

    def prepare_data(self) -> None:
        self.demos = None
        if not self.config.prior:
            return
        from hingelab.envs.tool_pick import observation_dim
        from hingelab.learning.high_level_prefill import concat_demos, high_level_transitions, look_ahead

        started = time.perf_counter()
        datasets = self.prior_datasets()
        self.demo_modes = [self.demo_action_mode(root) for root in datasets]
        parts, offset, filled = [], 0, []
        for root, mode in zip(datasets, self.demo_modes):
            skipped = []  # real episodes that lack what the relabelling needs: left out, named below
            part = high_level_transitions([root], self.config.reward, actions=mode, observation_dim=observation_dim(
                bool(self.config.env_kwargs.get("observe_extent", False))), skipped=skipped,
                encoder_path=self.config.env_kwargs.get("encoder_path"))
            part.episode_index = part.episode_index + offset  # one numbering over the datasets (look_ahead)
            offset = int(part.episode_index.max()) + 1
            parts.append(part)
            filled.append(prior_dataset_record(root, part, mode, skipped))
            if skipped:
                print(f"--from {root}: left out {len(skipped)} real episode(s) that cannot be relabelled "
                      f"(listed in {self.run_dir}/config.json under prior); the first: {skipped[0][1]}")
        self.demos = look_ahead(concat_demos(parts) if len(parts) > 1 else parts[0], self.config.demo_lookahead)
        self.demo_info = {"datasets": datasets, "demo_actions": self.demo_modes, "transitions": len(self.demos),
                          "episodes": int(len(np.unique(self.demos.episode_index))),
                          "sources": sorted({d["source"] for d in filled}), "filled_from": filled,
                          "seconds": round(time.perf_counter() - started, 2)}
        if not self.resume:  # config.json says which datasets (and sources) filled the buffer
            self.folder.record_run_fact("prior", self.demo_info)

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
        if self.demos is None:
            return
        if self.config.learns_from_demonstrations:
            from hingelab.learning.demo_sac import Demonstrations

            self.model.set_demonstrations(Demonstrations.from_transitions(self.demos))
            if new_run and self.config.bc_pretrain_updates:
                self.model.pretrain_actor(self.config.bc_pretrain_updates, self.config.batch_size,
                                          fit_std=self.config.bc_pretrain_std)
        if new_run and self.config.demo_offline_updates:
            self._warm_up_on_demos(self.config.demo_offline_updates)

    def _warm_up_on_demos(self, updates: int) -> None:
        """SAC updates from the demos alone (the ring buffer is still empty, or holds only them)."""
        from stable_baselines3.common.logger import configure

        self.model.set_logger(configure(folder=None, format_strings=[]))
        # SB3's own set-up of learn(): resets the envs once, which learn() then does not do again
        self.model._setup_learn(0, callback=None, reset_num_timesteps=False)
        self.model.train(gradient_steps=updates, batch_size=self.config.batch_size)

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

        if not hasattr(self, "_context"):  # hashes the low level's file: once per run, not per best model
            self._context = training_context(self.config.low_level)
        prior = None if self.demos is None else {**self.demo_info, "demo_share": self.config.demo_share,
                                                  "demo_actions": self.demo_modes,
                                                  "demo_lookahead": self.config.demo_lookahead}
        return super().provenance({**self._context, "prior": prior, **(extra or {})})

    def summary_extra(self) -> dict:
        return {"prior": None if self.demos is None else self.demo_info, "eval_episodes": self.config.eval_episodes}


class FlatRun(HighLevelRun):
    label = "train flat"
    dataset_description = "every training rollout of a hingelab train flat run"

    def env_record(self) -> dict:
        from hingelab.envs.tool_pick import MAX_SPEED
        from hingelab.envs.tool_pick_flat import FINGER_SCALE

        return {**SACRun.env_record(self),
                "action_scale": {"fingers_rad": FINGER_SCALE, "hand_velocity_m_s": MAX_SPEED}}


class PhaseCloneRun(HighLevelRun):
    """``hingelab train high --learner phase-clone``: the phase clone (``phase_clone``) fitted in a run folder.

    The run shares ``train high``'s folder, prior and evaluation: the scripted demos generated into
    ``RUNDIR/prior`` (their steps record the demonstrator's phases) or given with ``--from``;
    ``--clone-updates`` updates of the clone on them (of each of ``--clone-members`` nets, an ensemble); one held-out evaluation into ``metrics.csv``;
    ``model.zip`` (and ``best_model.zip``, the same policy) recording the env arguments, the low level's
    sha256, the encoder's fingerprint, the prior and the fit. No SAC and no env step of the run's own,
    so the run's dataset holds no training rollouts. ``--resume`` keeps a prior whose every dataset was
    written (a cut-off generation is made again) and fits the clone again from the start (a few
    minutes): the same weights, as the fit depends only on the demos and the seed.
    """

    label = "train high (phase clone)"

    def setup(self):
        configure_torch(self.config.torch_threads)
        self.started = time.perf_counter()
        if not self.resume:
            self.prepare_new_run()
            self.folder.write_run_files()
        self.prepare_data()
        self.make_evaluator()
        return self

    def train(self) -> dict:
        from hingelab.learning.phase_clone import PhaseClone, PhaseDemos, fit_phase_clone_members

        c = self.config
        demos = PhaseDemos.from_transitions(self.demos, where=", ".join(self.demo_info["datasets"]))
        if self.progress:
            print(f"{self.label} {self.name}: cloning {len(demos)} demo steps of {self.demo_info['episodes']} "
                  f"episodes ({c.clone_updates} updates, net {' x '.join(str(n) for n in c.net_arch)}"
                  f"{f', {c.clone_members} members' if c.clone_members > 1 else ''})")
        nets, fit = fit_phase_clone_members(demos, c.clone_members, tuple(c.net_arch), c.clone_updates,
                                            c.clone_batch_size, c.clone_learning_rate, c.seed, progress=self.progress)
        self.model = PhaseClone(nets)
        self.metrics.truncate_after(-1)  # a resumed run evaluates its clone again
        evaluation = {"env_steps": 0, "seed": c.seed, "updates": c.clone_updates, **self.evaluate_policy()}
        self.metrics.append(evaluation)
        self.model.hingelab_provenance = self.provenance({"fit": fit, "evaluation": evaluation})
        for name in ("best_model.zip", "model.zip"):  # one policy: the clone is not trained further
            self.model.save(self.run_dir / name)
        self.close_evaluator()
        self.best = {k: evaluation[k] for k in self.initial_best()} | {"env_steps": 0}
        return {"run_dir": str(self.run_dir), "env_steps": 0, "updates": c.clone_updates,
                "wall_time_s": time.perf_counter() - self.started, "last_evaluation": evaluation, "best": self.best,
                "fit": fit, "prefill": None, **self.summary_extra()}


def train_high(config: HighLevelTrainConfig, run_dir, resume: bool = False, progress: bool = True,
               name: str | None = None) -> dict:
    """Train (or resume) a high-level run (SAC, or the phase clone with ``learner="phase-clone"``; with a
    ``FlatTrainConfig``, a flat one); a summary dict."""
    cls = FlatRun if isinstance(config, FlatTrainConfig) else HighLevelRun
    if cls is HighLevelRun and config.learner == "phase-clone":
        cls = PhaseCloneRun
    return cls(config, Path(run_dir), resume=resume, progress=progress, name=name).setup().train()
