"""The settings of a residual SAC run (``hingelab train high --learner residual-sac``), saved with the run.

SAC learns a bounded residual over a frozen base policy (``hingelab.policies.residual``): the shipped
phase clone (``--base shipped``), a phase-clone checkpoint, or a clone the run fits first on its own
privileged prior (``--base fit``: the privileged buffer's demos, as the paper's ablation arm learns from
them). The privileged prior's demos also stay in every batch (``--demo-share``, RLPD's kept share).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hingelab.errors import ConfigError
from hingelab.learners.sac.config import SACTrainConfig
from hingelab.tasks import TOOL_PICK_ID
from hingelab.training.config_parts import PickReward, PickTask, PriorDemos, base_observation_form
from hingelab.training.run_config import option

BASES = ("shipped", "fit")  # or a phase-clone checkpoint's path
# The largest executed exploration noise (std, action units) per action dimension, below what the scripted
# demonstrator tolerates (``hingelab diagnose noise``, analysis/high-level/exploration/noise_tolerance.md:
# the latent goal 0.02 and 0.01, 20 of 20 picked; at 0.02 on the second latent 5 tool drops in 20; the hand's
# velocity 0.3 and more): half the latent's, a third of the velocity's
EXPLORATION_BOUND = (0.005, 0.005, 0.1, 0.1, 0.1)
# The residual's reach: on the latent goal no more than the noise it tolerates (the low level shakes the tool
# loose when its goal jumps), on the hand's velocity 0.2 (1.6 cm/s: the clone's misses are millimetres of
# lateral offset)
RESIDUAL_SCALE = (0.01, 0.01, 0.2, 0.2, 0.2)
ACTOR_Q = ("mean", "min", "lcb")  # ``ResidualSAC.actor_value``


@dataclass(frozen=True)
class ResidualSACConfig(PickTask, PickReward, PriorDemos, SACTrainConfig):
    base: str = option("shipped", "the frozen base: shipped (assets/checkpoints/high_level.zip, the phase clone), "
                                  "fit (a phase clone fitted first on the run's privileged prior, saved as "
                                  "RUNDIR/base.zip), or a phase-clone checkpoint", metavar="shipped|fit|CKPT")
    residual_scale: tuple = option(RESIDUAL_SCALE, "the largest correction the residual adds to each action "
                                                   "dimension, in (0, 1]: one number for all, or 5 (latent goal 0 "
                                                   "and 1, hand velocity x, y, z)", item=float, metavar="S")
    exploration_bound: tuple = option(EXPLORATION_BOUND, "the largest executed exploration noise (std, action "
                                                         "units) per action dimension: latent goal 0 and 1, hand "
                                                         "velocity x, y, z", item=float, metavar="STD")
    exploration_floor: tuple = option((), "the smallest executed exploration noise (std, action units) per action "
                                          "dimension, 5 numbers (default none: the temperature may shrink the noise "
                                          "to nothing, and the critics then see no action vary)", item=float,
                                      metavar="STD")
    # 2, not RLPD's 10: here an update costs in proportion to the critics (10: about 5x the twin critics' time,
    # measured on this 2-core machine), and a 100,000-step run must fit in about an hour
    critics: int = option(2, "critics in the ensemble (LayerNorm, one batched network)", flag="--critics")
    target_critics: int = option(2, "critics whose minimum makes the bootstrap target, drawn anew every update "
                                    "(REDQ)")
    critic_layer_norm: bool = option(True, "critics without LayerNorm", flag="--no-critic-layer-norm", negate=True)
    actor_start: int = option(5_000, "env steps before the actor and the temperature first move: until then the "
                                     "critics alone learn, on the prior's rollouts (and the demos)")
    critic_pretrain_updates: int = option(5_000, "critic-only updates on the prior's demos before the first env step",
                                          flag="--critic-pretrain", metavar="UPDATES")
    # 0.1: the pilots on the training sphere (exploration seed 100) kept the base's 20 of 20 through 15,000 steps
    # at 1.0 and 0.1; at 1.0 the residual stayed near 0.002 (of 0.2), at 0.1 near 0.01-0.02: room to correct
    residual_penalty: float = option(0.1, "weight of the pull of the residual back to 0 (the base) in the actor's "
                                          "loss, times the batch's mean |Q| (TD3+BC's scaling); 0: none")
    choose_by_q: bool = option(False, "the base proposes too (IBRL): act, bootstrap and deploy with the residual "
                                      "only where the critics value it above the base's own action (the policy "
                                      "file then carries the critics)", flag="--choose-by-q")
    actor_q: str = option("mean", "how the actor values its action across the critics: mean (REDQ's), min (SAC's "
                                  "twin minimum: pessimistic), or lcb (mean minus one standard deviation: "
                                  "pessimistic where the critics disagree)", choices=ACTOR_Q)
    actor_update: str = option("gradient", "how the actor learns: gradient (SAC's: follow the critics' action "
                                           "gradient) or awr (AWAC's: fit the batch's own residuals weighted by "
                                           "their advantage; no extrapolation to actions the data lacks)",
                               choices=("gradient", "awr"))
    awr_temperature: float = option(1.0, "temperature of --actor-update awr, in units of the batch's mean |advantage| "
                                         "(smaller: only the best actions count)")
    demo_share: float = option(0.25, "share of every batch drawn from the privileged prior's demos (0: none; "
                                     "--no-prior: no demos)")
    # the base fitted by the run (--base fit): the phase clone's settings
    clone_net_arch: tuple = option((256, 256), "hidden layers of the base clone (--base fit)", item=int)
    clone_updates: int = option(30_000, "Adam updates of the base clone (--base fit)", metavar="UPDATES")
    clone_batch_size: int = option(512, "demo steps per update of the base clone (--base fit)")
    clone_learning_rate: float = option(1e-3, "learning rate of the base clone (--base fit; cosine decay to 0)")
    # SAC settings whose defaults differ for this learner
    steps: int = option(100_000, "environment steps (transitions) in total, over all envs")
    max_episode_steps: int = option(200, "steps per episode before truncation (200 = 10 s, the paper's limit)")
    learning_starts: int = option(1_000, "env steps of the policy (the base and bounded noise) before the first "
                                         "update")
    ent_coef: str = option("auto_0.01", "entropy coefficient: auto_X (tuned, starting at X), auto, or a number")
    eval_every: int = option(10_000, "env steps between evaluations")
    eval_episodes: int = option(30, "held-out episodes per evaluation")

    kind = "residual-sac"
    env_id = TOOL_PICK_ID
    train_source = "high_level_training"
    action_level = "high"

    def __post_init__(self):
        self.check({**self.sac_checks(), **self.task_checks(), **self.prior_checks(),
                    "critics": self.critics >= 1, "target_critics": 1 <= self.target_critics <= self.critics,
                    "actor_start": self.actor_start >= 0, "residual_penalty": self.residual_penalty >= 0,
                    "critic_pretrain_updates": self.critic_pretrain_updates >= 0,
                    "demo_share": 0 <= self.demo_share <= 1, "awr_temperature": self.awr_temperature > 0,
                    "clone_net_arch": len(self.clone_net_arch) >= 1 and all(int(n) >= 1 for n in self.clone_net_arch),
                    "clone_updates": self.clone_updates >= 1, "clone_batch_size": self.clone_batch_size >= 1,
                    "clone_learning_rate": self.clone_learning_rate > 0})
        self.check_prior()
        _checked_scale(self.residual_scale)
        bound = tuple(float(b) for b in self.exploration_bound)
        if len(bound) != 5 or not all(b > 0 for b in bound):
            raise ConfigError(f"--exploration-bound takes 5 positive stds (latent goal 0 and 1, hand velocity x, y, "
                              f"z), not {list(self.exploration_bound)}")
        floor = tuple(float(f) for f in self.exploration_floor)
        if floor and (len(floor) != 5 or not all(0 < f <= b for f, b in zip(floor, bound))):
            raise ConfigError(f"--exploration-floor takes 5 positive stds, each at most --exploration-bound's "
                              f"({list(bound)}), not {list(self.exploration_floor)}")
        if self.base != "fit":  # observe as the base was trained to, where --env-kwargs does not say
            object.__setattr__(self, "env_kwargs", {**base_observation_form(self.base), **self.env_kwargs})
        if self.base == "fit" and not self.prior:
            raise ConfigError("--base fit clones the run's privileged prior: drop --no-prior, or give --base shipped "
                              "or a phase-clone checkpoint")
        if self.learns_from_demonstrations:
            raise ConfigError("the residual learner has no BC term: drop --bc-weight and --bc-pretrain (the base "
                              "holds the demonstrator)")
        if self.algorithm != "fast_sac":
            raise ConfigError("the residual learner runs on fast_sac's update: drop --algorithm")
        if self.update != "eager":
            raise ConfigError("the residual learner has its own update (an ensemble of critics): drop --update")

    @property
    def uses_demos(self) -> bool:
        return self.prior and self.demo_share > 0

    def log_std_max(self) -> list[float]:
        """The actor's log-std cap per dimension: the bound's std of the executed action over the scale."""
        scale = _checked_scale(self.residual_scale)
        return [math.log(b / s) for b, s in zip(self.exploration_bound, scale)]

    def log_std_min(self) -> list[float] | None:
        """The actor's log-std floor per dimension (None: none), as ``log_std_max`` from ``exploration_floor``."""
        if not self.exploration_floor:
            return None
        return [math.log(f / s) for f, s in zip(self.exploration_floor, _checked_scale(self.residual_scale))]



def _checked_scale(scale):
    """``hingelab.policies.residual.check_scale``, imported when a config is checked: the learner registers (and
    its flags are built) without loading torch."""
    from hingelab.policies.residual import check_scale

    return check_scale(scale)
