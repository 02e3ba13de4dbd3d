"""Every hyperparameter of a high-level run (``hingelab train high``) and of the flat baseline
(``hingelab train flat``), saved with the run.

``HighLevelTrainConfig`` trains SAC on ToolPick-v0 with a frozen low level inside (the shipped
low-level policy by default, ``--low-level privileged`` for the hinge servo, or a checkpoint),
perception and domain randomization on. The privileged prior (the paper's privileged replay
buffer): heuristic demos (``--from DATASET...``, or, without ``--from``, ``--prior-episodes``
episodes that the run generates itself into ``RUNDIR/prior``) as transitions of ToolPick-v0's
spaces (``high_level_prefill``), kept as ``--demo-share`` of every batch (0: the paper's plain
pre-fill of the ring buffer) and, with ``--bc-weight``, in the actor's BC term. ``--no-prior``
trains without them (the ablation's "no buffer" arm). ``FlatTrainConfig`` is the same recipe on
ToolPickFlat-v0 (one policy on the 9 finger deltas and the hand velocity, no low level).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from hingelab.envs.rewards import HighLevelRewardConfig
from hingelab.errors import ConfigError
from hingelab.learning.high_level_prior import PICK_SETS, PRIOR_OBJECTS, PRIOR_SOURCES
from hingelab.learning.run_config import option
from hingelab.learning.sac_config import SACTrainConfig

HIGH_ENV_ID = "hingelab/ToolPick-v0"
FLAT_ENV_ID = "hingelab/ToolPickFlat-v0"
DEMO_ACTIONS = ("auto", "reached", "recorded")
HIGH_LEARNERS = ("sac", "phase-clone")
_REWARD = HighLevelRewardConfig()


@dataclass(frozen=True)
class HighLevelTrainConfig(SACTrainConfig):
    steps: int = option(100_000, "environment steps (transitions) in total, over all envs")
    max_episode_steps: int = option(200, "steps per episode before truncation (200 = 10 s, the paper's limit)")
    learning_starts: int = option(256, "random steps before the first update (one batch: the demos fill the "
                                       "batches until then)")
    buffer_size: int = option(300_000, "replay buffer size (transitions, the demos not counted)")
    eval_every: int = option(10_000, "env steps between evaluations")
    # the task
    object: str = option("sphere", "object to pick: sphere, cube, cylinder, tetrahedron or mesh:PATH")
    size: float = option(0.02, "object width in m (a mesh's largest extent)")
    mass: float = option(0.01, "object mass in kg")
    low_level: str = option("policy", "the frozen low level: policy (the shipped low-level policy), privileged "
                                      "(the hinge servo) or a low-level checkpoint", metavar="CKPT|policy|privileged")
    placement_half_width: float = option(0.05, "half width in m of the square the object is placed in")
    c_h1: float = option(_REWARD.c_h1, "reward: success bonus")
    c_h2: float = option(_REWARD.c_h2, "reward: 1/m of the tool-object closeness term")
    c_h3: float = option(_REWARD.c_h3, "reward: weight of the object-target closeness term")
    c_h4: float = option(_REWARD.c_h4, "reward: 1/m of the object-target closeness term")
    c_h5: float = option(_REWARD.c_h5, "reward: penalty (a distance over 20 cm, a table collision)")
    # the privileged prior
    prior: bool = option(True, "train without the privileged prior (no heuristic demos: the ablation's "
                               "'no buffer' arm)", flag="--no-prior", negate=True)
    prior_source: str = option("scripted", "the demos the run generates into RUNDIR/prior when no --from is "
                                           "given: scripted (the heuristic's arm motion and hinge command as latent "
                                           "goals over the run's low level) or heuristic (the heuristic commanding "
                                           "the hinge directly, the paper's) or scripted-feedback (scripted "
                                           "without the object's size: the hinge closed by feedback on the perceived "
                                           "opening)", choices=PRIOR_SOURCES)
    prior_episodes: int = option(100, "episodes of the generated prior (over all its objects)")
    prior_action_noise: float = option(0.0, "std of Gaussian noise (action units) on the scripted demonstrator's "
                                            "executed hand velocity; the phase clone learns its clean actions, so the "
                                            "demos show recoveries (DART)", metavar="STD")
    prior_objects: str = option("run", "the objects of the generated prior: run (the run's --object and --size) or "
                                       "all (the pick table's 4 shapes x 3 sizes, the episodes shared evenly)",
                                choices=PRIOR_OBJECTS)
    demo_share: float = option(0.5, "share of every batch drawn from the demos, kept apart from the ring buffer "
                                    "(RLPD's 50/50); 0: the paper's plain pre-fill of the ring buffer")
    demo_actions: str = option("auto", "demo action: reached (the latent the tool reached, the paper's), "
                                       "recorded (the recorded command), or auto (recorded for scripted demos and "
                                       "real episodes that logged /hingelab/action, reached for the heuristic's)",
                             choices=DEMO_ACTIONS)
    demo_lookahead: int = option(1, "the reached latent this many steps after the step (1: the step's own, the "
                                    "paper's)")
    demo_offline_updates: int = option(0, "SAC updates on the demos alone before the first env step: the critic "
                                          "learns the demos' values before online data arrives (with --bc-weight "
                                          "the actor stays near them)", flag="--demo-warmup", metavar="UPDATES")
    # the demonstrations' recipe (defaults: what kept the cloned policy while SAC trained, issue 26's note)
    demo_bc_weight: float = option(0.4, "weight of the behaviour-cloning term on the demos in the actor loss "
                                        "(with --bc-q-scaled: TD3+BC's 1/alpha = 0.4)", flag="--bc-weight", metavar="W")
    bc_pretrain_updates: int = option(20_000, "behaviour-cloning updates of the actor on the demos before training",
                                      flag="--bc-pretrain", metavar="UPDATES")
    bc_pretrain_std: bool = option(True, "the BC pre-training also fits the actor's spread to the demos")
    bc_q_scaled: bool = option(True, "scale the BC term by the batch's mean |Q| (TD3+BC's normalization)")
    demo_q_filter: bool = option(False, "apply the BC term on every demonstration (the default here), not only "
                                        "where the critic prefers the demonstrated action", flag="--bc-no-q-filter",
                                 negate=True)
    eval_episodes: int = option(10, "held-out episodes per evaluation")
    # the learner
    learner: str = option("sac", "sac: SAC with the privileged prior (the paper's recipe, the flags above); "
                                 "phase-clone: behaviour cloning of the scripted demos with the demonstrator's phase "
                                 "as the policy's own memory (learning/phase_clone.py: the shipped policy's recipe; no "
                                 "SAC, no env steps of its own)", choices=HIGH_LEARNERS)
    clone_updates: int = option(30_000, "phase-clone: Adam updates of the clone", metavar="UPDATES")
    clone_batch_size: int = option(512, "phase-clone: demo steps per update")
    clone_learning_rate: float = option(1e-3, "phase-clone: Adam's learning rate (cosine decay to 0)")
    clone_members: int = option(1, "phase-clone: nets fitted on the same demos from different seeds; the policy "
                                   "acts on their mean action and most probable next phase (an ensemble)",
                                metavar="NETS")

    kind = "high-level"
    env_id = HIGH_ENV_ID
    train_source = "high_level_training"
    action_level = "high"

    def __post_init__(self):
        self.check({**self.sac_checks(), "size": self.size > 0, "mass": self.mass > 0,
                    "prior_episodes": self.prior_episodes >= (len(PICK_SETS) if self.prior_objects == "all" else 1),
                    "prior_objects": self.prior_objects in PRIOR_OBJECTS, "demo_share": 0 <= self.demo_share <= 1,
                    "demo_actions": self.demo_actions in DEMO_ACTIONS,
                    "prior_source": self.prior_source in PRIOR_SOURCES, "demo_lookahead": self.demo_lookahead >= 1,
                    "demo_offline_updates": self.demo_offline_updates >= 0,
                    "eval_episodes": self.eval_episodes >= 1, "placement_half_width": self.placement_half_width >= 0,
                    "learner": self.learner in HIGH_LEARNERS, "clone_updates": self.clone_updates >= 1,
                    "clone_batch_size": self.clone_batch_size >= 1, "clone_learning_rate": self.clone_learning_rate > 0,
                    "clone_members": self.clone_members >= 1,
                    "prior_action_noise": self.prior_action_noise >= 0})
        if self.learner == "phase-clone":
            if not self.prior:
                raise ConfigError("--learner phase-clone learns from the privileged prior's demos: drop --no-prior")
            if self.prior_source == "heuristic" and not self.from_datasets:
                raise ConfigError("--learner phase-clone needs demos that record the demonstrator's phases: "
                                  "--prior-source scripted (or scripted-feedback), not heuristic")
        if self.prior_action_noise and (self.prior_source == "heuristic" or self.from_datasets or not self.prior):
            raise ConfigError("--prior-action-noise is noise on the scripted demonstrator's actions as the run "
                              "generates its prior: drop it, or drop --from / --no-prior / --prior-source heuristic")
        if not self.prior:
            if self.from_datasets:
                raise ConfigError("--no-prior trains without demonstrations: drop --from")
            # no demos: nothing to clone or warm up on (the saved config says so)
            for name in ("demo_bc_weight", "bc_pretrain_updates", "demo_offline_updates"):
                object.__setattr__(self, name, type(getattr(self, name))(0))
        if self.learns_from_demonstrations and self.algorithm != "fast_sac":
            raise ConfigError("--bc-weight and --bc-pretrain work with --algorithm fast_sac")

    @property
    def reward(self) -> HighLevelRewardConfig:
        return HighLevelRewardConfig(c_h1=self.c_h1, c_h2=self.c_h2, c_h3=self.c_h3, c_h4=self.c_h4, c_h5=self.c_h5)

    def env_arguments(self) -> dict:
        """Keyword arguments of ``gymnasium.make(env_id, ...)`` (JSON: the reward as a dict)."""
        return {"object": self.object, "size": self.size, "mass": self.mass, "low_level": self.low_level,
                "randomize": self.randomize, "placement_half_width": self.placement_half_width,
                "max_episode_steps": self.max_episode_steps, "reward": asdict(self.reward), **self.env_kwargs}

    def recording_metadata(self) -> dict:
        return {"object_size": str(self.size), "low_level": self.low_level}


@dataclass(frozen=True)
class FlatTrainConfig(HighLevelTrainConfig):
    low_level: str = option("none", "no low level: the policy moves the fingers itself", cli=False)
    prior: bool = option(False, "the heuristic's demos are not in the flat action space", cli=False)

    kind = "flat"
    env_id = FLAT_ENV_ID
    train_source = "flat_training"
    action_level = "flat"

    def __post_init__(self):
        if self.prior or self.from_datasets:
            raise ConfigError("the flat baseline learns without demonstrations (the heuristic's are 5-D latent "
                              "goals and hand velocities, not finger moves): drop --from")
        super().__post_init__()

    def env_arguments(self) -> dict:
        arguments = super().env_arguments()
        del arguments["low_level"]
        return arguments

    def recording_metadata(self) -> dict:
        return {"object_size": str(self.size)}
