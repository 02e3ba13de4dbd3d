"""The hyperparameters every SAC learner of hingelab shares (``train low``, ``train high``, ``train flat``).

``SACTrainConfig`` is the base of each learner's frozen config: SAC itself, the rollout
envs, the run folder's bookkeeping and learning from demonstrations. A learner's config
adds its task's fields and says which env it trains on (``env_id``), what its rollouts are
(``train_source``) and how the env is built (``env_arguments``). Every field is a flag
(``hingelab.training.run_config``).
"""

from __future__ import annotations

from dataclasses import dataclass

from hingelab.arguments import positive_int
from hingelab.errors import ConfigError
from hingelab.training.config_parts import RunSettings
from hingelab.training.run_config import option

ALGORITHMS = ("sac", "fast_sac")
UPDATES = ("eager", "compiled", "fused")  # FastSAC's update (hingelab.learners.sac.fast_sac.UPDATES)


@dataclass(frozen=True)
class SACTrainConfig(RunSettings):
    steps: int = option(200_000, "environment steps (transitions) in total, over all envs")
    randomize: bool = option(True, "turn domain randomization off", flag="--no-randomize", negate=True)
    max_episode_steps: int = option(50, "steps per episode before truncation (20 Hz)")
    n_envs: int = option(2, "parallel rollout envs (processes unless --in-process: at most the cores)", flag="--envs",
                         parse=positive_int)
    subprocess_envs: bool = option(True, "step the envs in this process, one after another (several runs side by "
                                         "side)", flag="--in-process", negate=True)
    overlap: bool = option(False, "run each env step's gradient updates while the env processes compute the next "
                                  "step (one env gets a process too); the updates sample a buffer one env step "
                                  "behind, the policy acts with the newest weights (fast_sac only)")
    # SAC
    net_arch: tuple = option((256, 256), "hidden layers of the actor and both critics (ReLU)", item=int)
    learning_rate: float = option(3e-4, "Adam learning rate of actor, critics and entropy coefficient")
    buffer_size: int = option(300_000, "replay buffer size (transitions)")
    batch_size: int = option(256, "SAC batch")
    gamma: float = option(0.98, "discount factor")
    tau: float = option(0.005, "Polyak coefficient of the target critics")
    learning_starts: int = option(2_000, "random steps before the first update")
    train_freq: int = option(1, "env steps (per env) between updates")
    gradient_steps: int = option(1, "updates each time (with 2 envs, 1 update per 2 transitions)")
    ent_coef: str = option("auto", "entropy coefficient: auto (tuned to -dim(action) entropy) or a number")
    algorithm: str = option("fast_sac", "fast_sac: the same SAC updates, faster; sac: plain stable-baselines3",
                            choices=ALGORITHMS)
    update: str = option("eager", "fast_sac's gradient step: eager; compiled (one torch.compile'd function, after a "
                                  "compilation of tens of seconds); or fused (the gradients written out by hand "
                                  "into buffers made once, critics as one stacked network); the same algorithm "
                                  "each; compiled and fused need ent_coef auto and no BC term", choices=UPDATES)
    # bookkeeping
    eval_every: int = option(5_000, "env steps between evaluations")
    checkpoint_every: int = option(10_000, "env steps between resumable checkpoints")
    keep_checkpoints: int = option(2, "resumable checkpoints kept (the newest)")
    record: bool = option(True, "do not write the training rollouts (not advised)", flag="--no-record", negate=True)
    # demonstrations
    from_datasets: tuple = option((), "datasets whose transitions fill the replay buffer before training",
                                  flag="--from", metavar="DATASET")
    demo_bc_weight: float = option(0.0, "learn from the --from datasets as demonstrations: a Q-filtered "
                                        "behaviour-cloning term of this weight in the actor loss (Nair et al. "
                                        "2018; 0: plain SAC)", flag="--bc-weight", metavar="W")
    bc_pretrain_updates: int = option(0, "behaviour-cloning updates of the actor on the --from datasets before "
                                         "training", flag="--bc-pretrain", metavar="UPDATES")
    demo_q_filter: bool = option(True, "apply the BC term on every demonstration, not only where the critic "
                                       "prefers the demonstrated action", flag="--bc-no-q-filter", negate=True)
    bc_pretrain_std: bool = option(False, "the BC pre-training also fits the actor's spread to the demonstrations "
                                          "(else SAC's first rollouts scatter as widely as random ones)")
    bc_q_scaled: bool = option(False, "scale the BC term by the batch's mean |Q| (TD3+BC's normalization)")

    def sac_checks(self) -> dict[str, bool]:
        if self.overlap and self.algorithm != "fast_sac":
            raise ConfigError("--overlap is fast_sac's training loop: drop --algorithm sac or --overlap")
        if self.update in ("compiled", "fused"):
            problem = ("it is fast_sac's: drop --algorithm sac" if self.algorithm != "fast_sac" else
                       "it learns the temperature: give --ent-coef auto" if not str(self.ent_coef).startswith("auto")
                       else "it has no BC term: drop --bc-weight and --bc-pretrain" if self.learns_from_demonstrations
                       else None)
            if problem:
                raise ConfigError(f"--update {self.update} cannot run this config: {problem}, or --update eager")
        return {
            "steps": self.steps >= 0, "n_envs": self.n_envs >= 1, "batch_size": self.batch_size >= 1,
            "buffer_size": self.buffer_size >= self.batch_size, "learning_rate": self.learning_rate > 0,
            "gamma": 0 < self.gamma <= 1, "tau": 0 < self.tau <= 1, "train_freq": self.train_freq >= 1,
            "gradient_steps": self.gradient_steps >= 1, "eval_every": self.eval_every >= 1,
            "checkpoint_every": self.checkpoint_every >= 1, "max_episode_steps": self.max_episode_steps >= 1,
            "keep_checkpoints": self.keep_checkpoints >= 1, **self.run_checks(),
            "algorithm": self.algorithm in ALGORITHMS, "update": self.update in UPDATES,
            "demo_bc_weight": self.demo_bc_weight >= 0,
            "bc_pretrain_updates": self.bc_pretrain_updates >= 0, "learning_starts": self.learning_starts >= 0,
            "net_arch": len(self.net_arch) >= 1 and all(int(n) >= 1 for n in self.net_arch),
            "ent_coef": _valid_ent_coef(self.ent_coef),
        }

    @property
    def learns_from_demonstrations(self) -> bool:
        return bool(self.demo_bc_weight or self.bc_pretrain_updates)


def _valid_ent_coef(value: str) -> bool:
    text = str(value)
    if text == "auto" or text.startswith("auto_"):
        try:
            return text == "auto" or float(text[5:]) > 0
        except ValueError:
            return False
    try:
        return float(text) >= 0
    except ValueError:
        return False


__all__ = ["SACTrainConfig", "ALGORITHMS"]
