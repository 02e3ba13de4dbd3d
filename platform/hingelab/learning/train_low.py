"""``train_low``: SAC on ``hingelab/ToolShape-v0``, dataset-first, resumable.

A run folder holds everything the run made::

    RUNDIR/config.json      the LowLevelTrainConfig, seed, code version, env id
    RUNDIR/run.json         the curve label for ``hingelab report``
    RUNDIR/metrics.csv      one row per evaluation (env_steps, seed, success_rate, return, ...; success_rate
                            is the env's verdict, settled over the last 0.5 s: ``low_level_eval.summarize``)
    RUNDIR/dataset/         every training rollout, one MCAP episode each (source low_level_training)
    RUNDIR/checkpoints/     resumable checkpoints (model, replay buffer, RNG, counters)
    RUNDIR/model.zip        the last policy;  RUNDIR/best_model.zip  the best evaluated one

Checkpoints are taken where every env has just finished an episode (its next episode
is fully determined by its seed and count), after the updates of that step: resuming
from one continues the run as if it had never stopped. Evaluations run on fixed
held-out goals (``evaluation_goals``) with deterministic actions and do not touch the
training RNG.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError
from hingelab.learning import checkpoints as ckpt
from hingelab.learning.low_level_config import ENV_ID, LowLevelTrainConfig
from hingelab.learning.low_level_envs import (TRAIN_SOURCE, episode_counts, evaluation_goals, make_training_vec_env,
                                              set_episode_counts)
from hingelab.learning.low_level_eval import evaluate, make_eval_env, summarize
from hingelab.learning.sac_speed import configure_torch
from hingelab.provenance import code_version

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.csv"
DATASET_DIR = "dataset"
PROVENANCE_ATTRIBUTE = "hingelab_provenance"  # saved inside every model.zip


def algorithm_class(name: str):
    if name == "fast_sac":
        try:
            from hingelab.learning.sac_speed import FastSAC
            return FastSAC
        except ImportError:  # pragma: no cover - the module ships with hingelab
            pass
    from stable_baselines3 import SAC
    return SAC


def _provenance(config: LowLevelTrainConfig, extra: dict | None = None) -> dict:
    from hingelab.perception.encoder import shipped_encoder_fingerprint

    # the envs perceive through the shipped encoder: its latents are what the policy learned
    return {"env_id": ENV_ID, "config": config.to_dict(), "seed": config.seed,
            "encoder_fingerprint": shipped_encoder_fingerprint(), **code_version(), **(extra or {})}


def build_model(config: LowLevelTrainConfig, env):
    import torch
    from stable_baselines3 import HerReplayBuffer

    kwargs = {}
    if config.her:
        kwargs = {"replay_buffer_class": HerReplayBuffer,
                  "replay_buffer_kwargs": {"n_sampled_goal": 4, "goal_selection_strategy": "future",
                                           "copy_info_dict": True}}  # the effort term is in the infos
    cls = algorithm_class(config.algorithm)
    return cls("MultiInputPolicy", env, learning_rate=config.learning_rate, buffer_size=config.buffer_size,
               learning_starts=config.learning_starts, batch_size=config.batch_size, tau=config.tau,
               gamma=config.gamma, train_freq=config.train_freq, gradient_steps=config.gradient_steps,
               ent_coef=config.ent_coef, seed=config.seed, device="cpu", verbose=0,
               policy_kwargs={"net_arch": list(config.net_arch), "activation_fn": torch.nn.ReLU}, **kwargs)


def load_initial_weights(model, source) -> None:
    """Start ``model`` from a trained low-level policy (fine-tuning): the actor, critics and their
    targets, the optimizers and the entropy coefficient of ``source``, a ``PolicyLowLevel`` (it
    has refused another task's spaces or another encoder's latents)."""
    import torch

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


class MetricsLog:
    """``metrics.csv``, appended one evaluation at a time (flushed: a crash loses nothing written)."""

    def __init__(self, path: Path):
        self.path = path

    def rows(self) -> list[dict]:
        if not self.path.exists():
            return []
        with open(self.path, newline="") as f:
            return list(csv.DictReader(f))

    def truncate_after(self, env_steps: int) -> None:
        """Drop rows past a checkpoint we resume from (they will be evaluated again). Rows written
        before episode schema 2 (success_rate = last step, settled_success_rate) get today's names,
        so that a resumed run's success_rate is one verdict throughout."""
        from hingelab.analysis.learning_curves import old_metrics_renames

        rows = [r for r in self.rows() if int(float(r["env_steps"])) <= env_steps]
        renames = old_metrics_renames(rows[0]) if rows else {}
        rows = [{renames.get(k, k): v for k, v in r.items()} for r in rows]
        if self.path.exists():
            self.path.unlink()
        for r in rows:
            self.append(r)

    def _header(self) -> list[str] | None:
        if not self.path.exists():
            return None
        with open(self.path, newline="") as f:
            return next(csv.reader(f), None)

    def append(self, row: dict) -> None:
        """One row, under the file's header (a row's columns in another order go to their own
        columns; a row with new columns rewrites the file under the union, atomically)."""
        header = self._header()
        if header is not None and not set(row) <= set(header):
            rows = self.rows() + [row]
            fields = list(dict.fromkeys([*header, *row]))
            tmp = self.path.with_name(self.path.name + ".tmp")
            with open(tmp, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=fields, restval="")
                writer.writeheader()
                writer.writerows(rows)
                f.flush()
            tmp.replace(self.path)
            return
        with open(self.path, "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=header or list(row), restval="")
            if header is None:
                writer.writeheader()
            writer.writerow(row)
            f.flush()


class LowLevelRun:
    """One run folder: set up (new or resumed), train, evaluate, checkpoint."""

    def __init__(self, config: LowLevelTrainConfig, run_dir: Path, resume: bool = False, progress: bool = True,
                 name: str | None = None):
        self.run_dir = Path(run_dir)
        self.progress = progress
        config_path = self.run_dir / CONFIG_FILE
        if resume:
            if not config_path.exists():
                raise ConfigError(f"cannot resume: {config_path} does not exist; start the run without --resume")
            saved = LowLevelTrainConfig.load(config_path)
            # a resumed run keeps its config; only the step budget may grow
            self.config = replace(saved, steps=max(config.steps, saved.steps))
        else:
            if config_path.exists():
                raise ConfigError(f"{self.run_dir} already holds a run; continue it with --resume or pass another --out")
            self.config = config
        self.resume = resume
        run_file = self.run_dir / "run.json"
        if resume and run_file.exists():  # the dataset card carries the name it was made with
            name = json.loads(run_file.read_text()).get("name", name)
        self.name = name or self.run_dir.name
        self.metrics = MetricsLog(self.run_dir / METRICS_FILE)
        self.elapsed_before = 0.0
        self.best = {"success_rate": -1.0, "final_latent_distance": math.inf}
        self.prefill = None

    # ------------------------------------------------------------------ set-up
    def _write_run_files(self) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        doc = {"config": self.config.to_dict(), "seed": self.config.seed, "env_id": ENV_ID, **code_version(),
               "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        (self.run_dir / CONFIG_FILE).write_text(json.dumps(doc, indent=2))
        (self.run_dir / "run.json").write_text(json.dumps({"name": self.name}))

    def _dataset_dir(self) -> Path | None:
        if not self.config.record:
            return None
        from hingelab.episodes import create_dataset

        root = self.run_dir / DATASET_DIR
        dataset_config = {k: v for k, v in self.config.to_dict().items() if k != "steps"}
        if not (self.resume and (root / "dataset.json").exists()):  # a resumed run keeps its card (and its name)
            create_dataset(root, name=f"{self.name}-rollouts", source=TRAIN_SOURCE, config=dataset_config,
                           seed=self.config.seed, description="every training rollout of a hingelab train low run")
        if self.resume:  # episodes that were running when the run stopped are replayed from their seeds
            for partial in (root / "episodes").glob("*.partial"):
                partial.unlink()
        return root

    def setup(self):
        configure_torch(self.config.torch_threads)
        init_source = None
        if not self.resume:
            if self.config.init_from:  # read (and a bad one refused) before the run folder is made
                from hingelab.envs.low_level import PolicyLowLevel

                init_source = PolicyLowLevel(self.config.init_from)
            self._write_run_files()
        self.env = make_training_vec_env(self.config, self._dataset_dir())
        eval_args = {**self.config.env_arguments()}
        self.eval_env = make_eval_env(eval_args)
        unwrapped = self.eval_env.unwrapped
        self.goals = evaluation_goals(unwrapped.calibration, unwrapped.reachable_range,
                                      self.config.eval_goals_per_region)
        cls = algorithm_class(self.config.algorithm)
        state = None
        latest = ckpt.latest_checkpoint(self.run_dir) if self.resume else None
        if self.resume and latest is None:
            raise ConfigError(f"cannot resume: {self.run_dir} has no complete checkpoint yet; start it anew "
                              "(delete the folder or pass another --out)")
        if latest is not None:
            self.model, state = ckpt.load_checkpoint(latest, cls, self.env)
            self.checkpoint_from = latest
        else:
            self.model = build_model(self.config, self.env)
            self.checkpoint_from = None
            if init_source is not None:  # a new run (a resumed one starts from its own checkpoint)
                load_initial_weights(self.model, init_source)
        setattr(self.model, PROVENANCE_ATTRIBUTE, _provenance(self.config))
        if state is not None:
            self.elapsed_before = state["elapsed_s"]
            self.best = state["best"]
            self.next_eval, self.next_checkpoint = state["next_eval"], state["next_checkpoint"]
            set_episode_counts(self.env, state["episode_counts"])
            self.metrics.truncate_after(self.model.num_timesteps)
            self.mid_episode = state.get("mid_episode", False)
            self._state_rng = (state["rng"], state["action_space_rng"])
        else:
            self.next_eval, self.next_checkpoint = 0, self.config.checkpoint_every
            self.mid_episode = False
            self._state_rng = None
        demos = self.config.learns_from_demonstrations
        if self.config.from_datasets and (state is None or demos):
            self._use_datasets(prefill=state is None, demos=demos, pretrain=state is None)
        return self

    def _use_datasets(self, prefill: bool, demos: bool, pretrain: bool) -> None:
        """The --from datasets, read once: replay pre-fill (new runs) and demonstrations (BC
        pre-training for new runs, the actor's BC term for every session of the run)."""
        from hingelab.learning.replay_prefill import fill_from_transitions, read_transitions

        started = time.perf_counter()
        transitions, episodes = read_transitions(self.config.from_datasets, progress=self.progress)
        read_s = time.perf_counter() - started
        if demos:  # before the pre-fill relabels rewards: demonstrations need only observations and actions
            from hingelab.learning.demo_bc import DemoBC, pretrain_actor

            demo = DemoBC.from_transitions(transitions, self.config.demo_bc_weight, q_filter=self.config.demo_q_filter)
            if pretrain and self.config.bc_pretrain_updates:
                pretrain_actor(self.model, demo, self.config.bc_pretrain_updates, self.config.batch_size)
            self.model.demo_bc = demo if self.config.demo_bc_weight else None
        if prefill:
            # rewards recomputed with this run's reward (the datasets may be recorded with or without effort)
            self.prefill = fill_from_transitions(self.model.replay_buffer, transitions, episodes,
                                                 len(self.config.from_datasets), read_s, self.eval_env.unwrapped)

    # ------------------------------------------------------------------ pieces the callback calls
    def evaluate_now(self, env_steps: int, extra: dict) -> dict:
        episodes = evaluate(self.model, self.eval_env, self.goals)
        row = {"env_steps": env_steps, "seed": self.config.seed, **summarize(episodes), **extra}
        self.metrics.append(row)
        if (row["success_rate"], -row["final_latent_distance"]) > (self.best["success_rate"],
                                                                    -self.best["final_latent_distance"]):
            self.best = {"success_rate": row["success_rate"], "final_latent_distance": row["final_latent_distance"],
                         "env_steps": env_steps}
            setattr(self.model, PROVENANCE_ATTRIBUTE, _provenance(self.config, {"evaluation": row}))
            self.model.save(self.run_dir / "best_model.zip", exclude=["replay_buffer"])
        return row

    def checkpoint_now(self, elapsed_s: float, mid_episode: bool) -> Path:
        counts = episode_counts(self.env)
        if not mid_episode:
            # the envs have already reset into their next episodes; on resume they reset into them again
            counts = [c - 1 for c in counts]
        state = {"elapsed_s": elapsed_s, "best": self.best, "next_eval": self.next_eval,
                 "next_checkpoint": self.next_checkpoint, "episode_counts": counts, "mid_episode": mid_episode,
                 # random actions before learning_starts come from the action space's own generator
                 "action_space_rng": self.model.action_space.np_random.bit_generator.state}
        return ckpt.save_checkpoint(self.run_dir, self.model, state, keep=self.config.keep_checkpoints)

    # ------------------------------------------------------------------ training
    def train(self) -> dict:
        if self.config.offline_updates:
            return self._train_offline()
        return self._train_online()

    def _train_online(self) -> dict:
        from hingelab.learning.training_callback import TrainingCallback

        remaining = self.config.steps - self.model.num_timesteps
        callback = TrainingCallback(self, progress=self.progress)
        if self._state_rng is not None:  # last, after everything that seeds on load
            ckpt.restore_rng_states(self._state_rng[0])
            self.model.action_space.np_random.bit_generator.state = self._state_rng[1]
        self.model.learn(total_timesteps=max(remaining, 0), callback=callback, reset_num_timesteps=False,
                         log_interval=None)
        callback.finish()
        return self._finish(callback.elapsed())

    def _train_offline(self) -> dict:
        from tqdm import tqdm
        from stable_baselines3.common.logger import configure

        model, total = self.model, self.config.offline_updates
        model.set_logger(configure(folder=None, format_strings=[]))
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
        return self._finish(time.perf_counter() - start)

    def _finish(self, elapsed_s: float) -> dict:
        setattr(self.model, PROVENANCE_ATTRIBUTE, _provenance(self.config, {"final_env_steps": self.model.num_timesteps}))
        self.model.save(self.run_dir / "model.zip", exclude=["replay_buffer"])
        rows = self.metrics.rows()
        last = rows[-1] if rows else {}
        self.env.close()
        self.eval_env.close()
        return {"run_dir": str(self.run_dir), "env_steps": self.model.num_timesteps, "updates": self.model._n_updates,
                "eval_goals": len(self.goals),
                "wall_time_s": elapsed_s, "last_evaluation": last, "best": self.best,
                "prefill": None if self.prefill is None else self.prefill.__dict__ | {
                    "transitions_per_s": self.prefill.transitions_per_s}}


def train_low(config: LowLevelTrainConfig, run_dir, resume: bool = False, progress: bool = True,
              name: str | None = None) -> dict:
    """Train (or resume) a low-level run; returns a summary dict (see ``LowLevelRun._finish``)."""
    return LowLevelRun(config, Path(run_dir), resume=resume, progress=progress, name=name).setup().train()
