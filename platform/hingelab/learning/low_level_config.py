"""Every hyperparameter of a low-level run (``hingelab train low``), saved with the run.

One frozen dataclass: the CLI fills it, ``RUNDIR/config.json`` stores it with the code
version and seed, and ``--resume`` reads it back (a resumed run keeps its config).
Defaults follow the paper where it speaks (SAC, 2 x 256 ReLU, the effort reward, 20 Hz,
domain randomization) and SAC's usual values where it does not.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from hingelab.errors import ConfigError

ENV_ID = "hingelab/ToolShape-v0"


@dataclass(frozen=True)
class LowLevelTrainConfig:
    steps: int = 200_000  # environment steps (transitions) in total, over all envs
    seed: int = 0
    use_effort: bool = True  # False: the paper's ablation without the effort reward
    effort_weight: float = 50.0  # c2: reward per m of mean tool-point displacement per step (LowLevelRewardConfig)
    drift_weight: float = 0.0  # c4: reward per m of privileged tool drift beyond 5 mm, per step (0: off, the paper's)
    her: bool = False  # HER relabelling ("future", 4 goals per transition)
    goal_sampling: str = "reachable"  # training goals; see ToolShape-v0 "Goals"
    goal_openings: tuple | None = None  # (low, high) rad: reachable goals from this band only (an expert's)
    randomize: bool = True  # delays, gains, friction (paper)
    max_episode_steps: int = 50  # 2.5 s at 20 Hz
    n_envs: int = 2  # rollouts per vectorized step
    subprocess_envs: bool = True  # one process per env when n_envs > 1 (False: all in this process)
    # SAC
    net_arch: tuple = (256, 256)  # ReLU, actor and both critics (paper)
    learning_rate: float = 3e-4
    buffer_size: int = 300_000
    batch_size: int = 256
    gamma: float = 0.98  # 50-step episodes: a horizon of ~50 steps
    tau: float = 0.005
    learning_starts: int = 2_000
    train_freq: int = 1  # env steps (per env) between updates
    gradient_steps: int = 1  # updates each time: with n_envs=2, 1 update per 2 transitions
    ent_coef: str = "auto"
    algorithm: str = "fast_sac"  # "sac": plain stable-baselines3; "fast_sac": same math, faster updates
    torch_threads: int = 1
    # bookkeeping
    eval_every: int = 5_000  # env steps between evaluations
    eval_goals_per_region: int = 4  # held-out goals per third of the reachable opening range
    checkpoint_every: int = 10_000  # env steps between resumable checkpoints
    keep_checkpoints: int = 2
    record: bool = True  # every training rollout into RUNDIR/dataset (MCAP)
    from_datasets: tuple = ()  # datasets whose transitions pre-fill the replay buffer
    offline_updates: int = 0  # > 0: train from the datasets alone, this many updates
    demo_bc_weight: float = 0.0  # > 0: Q-filtered BC on the --from datasets in the actor loss (demo_bc)
    bc_pretrain_updates: int = 0  # behaviour-cloning updates of the actor on --from before training
    demo_q_filter: bool = True  # BC term only where the critic prefers the demo action (Nair et al.)
    init_from: str = ""  # a low-level SAC zip whose weights start a new run (fine-tuning; "": fresh weights)
    env_kwargs: dict = field(default_factory=dict)  # more ToolShape-v0 arguments

    def __post_init__(self):
        checks = {
            "steps": self.steps >= 0, "n_envs": self.n_envs >= 1, "batch_size": self.batch_size >= 1,
            "buffer_size": self.buffer_size >= self.batch_size, "learning_rate": self.learning_rate > 0,
            "gamma": 0 < self.gamma <= 1, "tau": 0 < self.tau <= 1, "train_freq": self.train_freq >= 1,
            "gradient_steps": self.gradient_steps >= 1, "eval_every": self.eval_every >= 1,
            "checkpoint_every": self.checkpoint_every >= 1, "max_episode_steps": self.max_episode_steps >= 1,
            "keep_checkpoints": self.keep_checkpoints >= 1, "offline_updates": self.offline_updates >= 0,
            "eval_goals_per_region": self.eval_goals_per_region >= 1, "torch_threads": self.torch_threads >= 1,
            "goal_sampling": self.goal_sampling in ("normal", "reachable", "reachable_open", "reachable_closed"),
            "algorithm": self.algorithm in ("sac", "fast_sac"),
            "demo_bc_weight": self.demo_bc_weight >= 0, "effort_weight": self.effort_weight >= 0,
            "drift_weight": self.drift_weight >= 0, "bc_pretrain_updates": self.bc_pretrain_updates >= 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"invalid low-level training config: {', '.join(f'{b}={getattr(self, b)!r}' for b in bad)}")
        if self.goal_openings is not None:
            band = tuple(float(v) for v in self.goal_openings)
            if len(band) != 2 or not band[0] < band[1] or self.goal_sampling != "reachable":
                raise ConfigError(f"--goal-openings {self.goal_openings} must be LOW:HIGH rad with LOW < HIGH, "
                                  "and --goals reachable")
            object.__setattr__(self, "goal_openings", band)
        if self.drift_weight and not self.use_effort:
            raise ConfigError("--drift-weight adds to the effort term, which --no-effort switches off: drop one")
        if self.offline_updates and not self.from_datasets:
            raise ConfigError("offline training (--offline N) needs datasets to learn from: add --from DATASET")
        if self.learns_from_demonstrations and not self.from_datasets:
            raise ConfigError("learning from demonstrations (--bc-weight, --bc-pretrain) needs them: add --from DATASET")
        if self.init_from and self.offline_updates:
            raise ConfigError("--init-from starts online training from a policy; --offline trains from datasets: drop one")
        if self.learns_from_demonstrations and (self.algorithm != "fast_sac" or self.her):
            raise ConfigError("--bc-weight and --bc-pretrain work with --algorithm fast_sac and without --her")

    @property
    def learns_from_demonstrations(self) -> bool:
        return bool(self.demo_bc_weight or self.bc_pretrain_updates)

    def to_dict(self) -> dict:
        out = asdict(self)
        out["net_arch"] = list(self.net_arch)
        out["from_datasets"] = [str(p) for p in self.from_datasets]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "LowLevelTrainConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown low-level config keys {unknown}; this run was made by another hingelab version")
        data = dict(data)
        data["net_arch"] = tuple(data.get("net_arch", cls.net_arch))
        data["from_datasets"] = tuple(data.get("from_datasets", ()))
        return cls(**data)

    @classmethod
    def load(cls, path: Path) -> "LowLevelTrainConfig":
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"cannot read the run config {path}: {exc}") from exc
        return cls.from_dict(data.get("config", data))

    def env_arguments(self) -> dict:
        """Keyword arguments of ``gymnasium.make(ENV_ID, ...)`` for this run."""
        return {"use_effort": self.use_effort, "effort_weight": self.effort_weight, "drift_weight": self.drift_weight,
                "goal_sampling": self.goal_sampling, "randomize": self.randomize,
                "max_episode_steps": self.max_episode_steps,
                **({"goal_openings": self.goal_openings} if self.goal_openings is not None else {}), **self.env_kwargs}
