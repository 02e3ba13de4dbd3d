"""Every hyperparameter of a SAC run on ToolPick-v0 (``hingelab train high``) and of the flat baseline
(``hingelab train flat``), saved with the run.

``HighLevelTrainConfig`` trains SAC on ToolPick-v0 with a frozen low level inside (the shipped
low-level policy by default, ``--low-level privileged`` for the hinge servo, or a checkpoint),
perception and domain randomization on. The privileged prior (the paper's privileged replay
buffer, ``PriorDemos``): demos from ``--from DATASET...`` or generated into ``RUNDIR/prior``, as
transitions of ToolPick-v0's spaces (``hingelab.training.high_level_demos``), kept as ``--demo-share``
of every batch (0: the paper's plain pre-fill of the ring buffer) and, with ``--bc-weight``, in the
actor's BC term. ``--no-prior`` trains without them (the ablation's "no buffer" arm).
``FlatTrainConfig`` is the same task on ToolPickFlat-v0 (one policy on the 9 finger deltas and the
hand velocity, no low level, no demos).
"""

from __future__ import annotations

from dataclasses import dataclass

from hingelab.errors import ConfigError
from hingelab.learners.sac.config import SACTrainConfig
from hingelab.tasks import TOOL_PICK_FLAT_ID, TOOL_PICK_ID
from hingelab.training.config_parts import PickReward, PickTask, PriorDemos
from hingelab.training.run_config import option

HIGH_ENV_ID = TOOL_PICK_ID
FLAT_ENV_ID = TOOL_PICK_FLAT_ID
# keys of the config.json of runs made when the phase clone's settings lived in this config too
_CLONE_KEYS = frozenset({"learner", "clone_updates", "clone_batch_size", "clone_learning_rate", "clone_members"})


@dataclass(frozen=True)
class HighLevelTrainConfig(PickTask, PickReward, PriorDemos, SACTrainConfig):
    steps: int = option(100_000, "environment steps (transitions) in total, over all envs")
    learning_starts: int = option(256, "random steps before the first update (one batch: the demos fill the "
                                       "batches until then)")
    buffer_size: int = option(300_000, "replay buffer size (transitions, the demos not counted)")
    eval_every: int = option(10_000, "env steps between evaluations")
    # SAC from the prior's demos
    demo_share: float = option(0.5, "share of every batch drawn from the demos, kept apart from the ring buffer "
                                    "(RLPD's 50/50); 0: the paper's plain pre-fill of the ring buffer")
    demo_offline_updates: int = option(0, "SAC updates on the demos alone before the first env step: the critic "
                                          "learns the demos' values before online data arrives (with --bc-weight "
                                          "the actor stays near them)", flag="--demo-warmup", metavar="UPDATES")
    # the recipe that kept the cloned behaviour longest while SAC trained (analysis/high-level/README.md)
    demo_bc_weight: float = option(0.4, "weight of the behaviour-cloning term on the demos in the actor loss "
                                        "(with --bc-q-scaled: TD3+BC's 1/alpha = 0.4)", flag="--bc-weight", metavar="W")
    bc_pretrain_updates: int = option(20_000, "behaviour-cloning updates of the actor on the demos before training",
                                      flag="--bc-pretrain", metavar="UPDATES")
    bc_pretrain_std: bool = option(True, "the BC pre-training also fits the actor's spread to the demos")
    bc_q_scaled: bool = option(True, "scale the BC term by the batch's mean |Q| (TD3+BC's normalization)")
    demo_q_filter: bool = option(False, "apply the BC term on every demonstration (the default here), not only "
                                        "where the critic prefers the demonstrated action", flag="--bc-no-q-filter",
                                 negate=True)

    kind = "high-level"
    env_id = HIGH_ENV_ID
    train_source = "high_level_training"
    action_level = "high"
    legacy_keys = _CLONE_KEYS

    def __post_init__(self):
        if not self.prior:
            # no demos: nothing to clone or warm up on (the saved config says so; before the checks, which ask
            # whether the run learns from demonstrations)
            for name in ("demo_bc_weight", "bc_pretrain_updates", "demo_offline_updates"):
                object.__setattr__(self, name, type(getattr(self, name))(0))
        self.check({**self.sac_checks(), **self.task_checks(), **self.prior_checks(),
                    "demo_share": 0 <= self.demo_share <= 1, "demo_offline_updates": self.demo_offline_updates >= 0})
        self.check_prior()
        if self.learns_from_demonstrations and self.algorithm != "fast_sac":
            raise ConfigError("--bc-weight and --bc-pretrain work with --algorithm fast_sac")


@dataclass(frozen=True)
class FlatTrainConfig(PickTask, PickReward, SACTrainConfig):
    steps: int = option(100_000, "environment steps (transitions) in total, over all envs")
    learning_starts: int = option(256, "random steps before the first update")
    eval_every: int = option(10_000, "env steps between evaluations")
    low_level: str = option("none", "no low level: the policy moves the fingers itself", cli=False)
    from_datasets: tuple = option((), "the heuristic's demos are not in the flat action space", cli=False)

    kind = "flat"
    env_id = FLAT_ENV_ID
    train_source = "flat_training"
    action_level = "flat"
    # the demo settings that runs of the flat baseline recorded when it shared train high's config
    legacy_keys = _CLONE_KEYS | frozenset(PriorDemos.__dataclass_fields__) - {"from_datasets"} | frozenset(
        {"demo_share", "demo_offline_updates", "demo_bc_weight", "bc_pretrain_updates", "bc_pretrain_std",
         "bc_q_scaled", "demo_q_filter"})

    def __post_init__(self):
        if self.from_datasets:
            raise ConfigError("the flat baseline learns without demonstrations (the heuristic's are 5-D latent "
                              "goals and hand velocities, not finger moves): drop --from")
        self.check({**self.sac_checks(), **self.task_checks()})

    def env_arguments(self) -> dict:
        arguments = super().env_arguments()
        del arguments["low_level"]
        return arguments

    def recording_metadata(self) -> dict:
        return {"object_size": str(self.size)}
