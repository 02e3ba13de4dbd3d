"""The settings of a phase-clone run (``hingelab train high --learner phase-clone``), saved with the run."""

from __future__ import annotations

from dataclasses import dataclass

from hingelab.errors import ConfigError
from hingelab.tasks import TOOL_PICK_ID
from hingelab.training.config_parts import PickReward, PickTask, PriorDemos, RunSettings
from hingelab.training.run_config import option

# keys of the config.json of phase-clone runs made when this learner shared the SAC learner's config
_SAC_KEYS = frozenset({
    "learner", "steps", "n_envs", "subprocess_envs", "learning_rate", "buffer_size", "batch_size", "gamma", "tau",
    "learning_starts", "train_freq", "gradient_steps", "ent_coef", "algorithm", "eval_every", "checkpoint_every",
    "keep_checkpoints", "record", "demo_bc_weight", "bc_pretrain_updates", "demo_q_filter", "bc_pretrain_std",
    "bc_q_scaled", "demo_share", "demo_offline_updates"})


@dataclass(frozen=True)
class PhaseCloneConfig(PriorDemos, PickReward, PickTask, RunSettings):
    net_arch: tuple = option((256, 256), "hidden layers of the clone's network (ReLU)", item=int)
    clone_updates: int = option(30_000, "Adam updates of the clone", metavar="UPDATES")
    clone_batch_size: int = option(512, "demo steps per update")
    clone_learning_rate: float = option(1e-3, "Adam's learning rate (cosine decay to 0)")
    clone_members: int = option(1, "nets fitted on the same demos from different seeds; the policy acts on their "
                                   "mean action and most probable next phase (an ensemble)", metavar="NETS")
    jobs: int = option(1, "worker processes (spawned, one torch thread each) that share the run's work: the "
                          "prior's episodes, the members' fits, the held-out evaluations (and DAgger's rollouts), "
                          "merged in order: the same prior, weights, labels and metrics as --jobs 1 at --threads 1, "
                          "sooner; at most the cores unless --allow-oversubscribe; a --resume may change it",
                       metavar="N")

    kind = "phase-clone"
    env_id = TOOL_PICK_ID
    train_source = "high_level_training"
    action_level = "high"
    legacy_keys = _SAC_KEYS

    def __post_init__(self):
        if not isinstance(self.jobs, int) or self.jobs < 1:
            raise ConfigError(f"--jobs {self.jobs}: give 1 or more worker processes (1: the run in this process)")
        self.check({**self.run_checks(), **self.task_checks(), **self.prior_checks(),
                    "net_arch": len(self.net_arch) >= 1 and all(int(n) >= 1 for n in self.net_arch),
                    "clone_updates": self.clone_updates >= 1, "clone_batch_size": self.clone_batch_size >= 1,
                    "clone_learning_rate": self.clone_learning_rate > 0, "clone_members": self.clone_members >= 1})
        self.check_prior()
        if not self.prior:
            raise ConfigError("--learner phase-clone learns from the privileged prior's demos: drop --no-prior")
        if self.prior_source == "heuristic" and not self.from_datasets:
            raise ConfigError("--learner phase-clone needs demos that record the demonstrator's phases: "
                              "--prior-source scripted (or scripted-feedback), not heuristic")
