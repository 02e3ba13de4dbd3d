"""The parts a learner's config is composed of: frozen dataclasses whose fields are flags
(``hingelab.training.run_config.option``), combined by inheritance into one flat config per learner.

* ``RunSettings``: what every run has (seed, torch threads, extra env arguments, corrupt input);
* ``PickTask`` and ``PickReward``: ToolPick-v0 as a run trains and evaluates on it (object, low level,
  randomization, episode length, held-out episodes; the reward's weights);
* ``PriorDemos``: the privileged demonstrations of the high level (the prior a run generates into
  ``RUNDIR/prior``, or ``--from`` datasets) and how their actions are read.

A learner's config (``hingelab.learners.<name>.config``) lists the parts it uses and adds its own
fields; ``hingelab train LEVEL --learner NAME`` builds its flags from that config alone.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from hingelab.envs.reward_config import HIGH_LEVEL_REWARD_MODES, LEGACY_MODE, HighLevelRewardConfig
from hingelab.errors import ConfigError
from hingelab.seeds import seed_argument
from hingelab.training.run_config import RunConfig, option

DEMO_ACTIONS = ("auto", "reached", "recorded")
PRIOR_SOURCES = ("scripted", "scripted-feedback", "heuristic")  # the demonstrators of a generated prior
PRIOR_OBJECTS = ("run", "all")
_REWARD = HighLevelRewardConfig()


@dataclass(frozen=True)
class RunSettings(RunConfig):
    seed: int = option(0, "run seed: weights, episodes, batches; in [0, 2**32)", parse=seed_argument)
    torch_threads: int = option(1, "torch threads", flag="--threads")
    env_kwargs: dict = option(None, "more arguments of the env, as a JSON object", default_factory=dict)
    on_corrupt: str = option("stop", "episode files of the --from datasets that cannot be read (corrupt, cut off): "
                                     "stop names them all and ends; skip leaves them out and says how many",
                             choices=("stop", "skip"))

    env_id = ""  # class attributes of each learner's config: the env it trains on,
    train_source = ""  # the source of its recorded rollouts,
    action_level = ""  # and the level its actions are on

    def run_checks(self) -> dict[str, bool]:
        return {"torch_threads": self.torch_threads >= 1, "on_corrupt": self.on_corrupt in ("stop", "skip")}

    def env_arguments(self) -> dict:  # pragma: no cover - every learner defines it
        raise NotImplementedError

    def recording_metadata(self) -> dict:
        """Extra metadata of every recorded training episode."""
        return {}


@dataclass(frozen=True)
class PickTask(RunConfig):
    object: str = option("sphere", "object to pick: sphere, cube, cylinder, tetrahedron, mesh:PATH or "
                                   "family:NAME[:SEED] (a new object each episode, --size its cap)")
    size: float = option(0.02, "object width in m (a mesh's largest extent)")
    mass: float = option(0.01, "object mass in kg")
    low_level: str = option("policy", "the frozen low level: policy (the shipped low-level policy), privileged "
                                      "(the hinge servo) or a low-level checkpoint", metavar="CKPT|policy|privileged")
    placement_half_width: float = option(0.05, "half width in m of the square the object is placed in")
    randomize: bool = option(True, "turn domain randomization off", flag="--no-randomize", negate=True)
    max_episode_steps: int = option(200, "steps per episode before truncation (200 = 10 s, the paper's limit)")
    eval_episodes: int = option(10, "held-out episodes per evaluation")

    def task_checks(self) -> dict[str, bool]:
        return {"size": self.size > 0, "mass": self.mass > 0, "placement_half_width": self.placement_half_width >= 0,
                "max_episode_steps": self.max_episode_steps >= 1, "eval_episodes": self.eval_episodes >= 1}

    def env_arguments(self) -> dict:
        """Keyword arguments of ``gymnasium.make(env_id, ...)`` (JSON: the reward as a dict)."""
        return {"object": self.object, "size": self.size, "mass": self.mass, "low_level": self.low_level,
                "randomize": self.randomize, "placement_half_width": self.placement_half_width,
                "max_episode_steps": self.max_episode_steps, "reward": asdict(self.reward), **self.env_kwargs}

    def recording_metadata(self) -> dict:
        return {"object_size": str(self.size), "low_level": self.low_level}


@dataclass(frozen=True)
class PickReward(RunConfig):
    c_h1: float = option(_REWARD.c_h1, "reward: success bonus")
    c_h2: float = option(_REWARD.c_h2, "reward: 1/m of the tool-object closeness term")
    c_h3: float = option(_REWARD.c_h3, "reward: weight of the object-target closeness term")
    c_h4: float = option(_REWARD.c_h4, "reward: 1/m of the object-target closeness term")
    c_h5: float = option(_REWARD.c_h5, "reward: penalty (a distance over 20 cm, a table collision)")
    reward_mode: str = option(_REWARD.mode, "absorbing: success also pays the discounted value of staying at the "
                                            "target, gamma (1 + c_h3) / (1 - gamma), so finishing beats lingering; "
                                            "paper: the paper's eq. 8-10 alone (hingelab.envs.rewards)",
                              choices=HIGH_LEVEL_REWARD_MODES)

    defaults_before = {"reward_mode": LEGACY_MODE}  # run configs saved before the modes: the paper's reward

    @property
    def reward(self) -> HighLevelRewardConfig:
        """The env's reward config; its discount is the learner's (``gamma``), where the config has one."""
        gamma = getattr(self, "gamma", _REWARD.gamma)
        return HighLevelRewardConfig(c_h1=self.c_h1, c_h2=self.c_h2, c_h3=self.c_h3, c_h4=self.c_h4, c_h5=self.c_h5,
                                     mode=self.reward_mode, gamma=gamma)


@dataclass(frozen=True)
class PriorDemos(RunConfig):
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
    from_datasets: tuple = option((), "datasets of demonstrations instead of the generated prior",
                                  flag="--from", metavar="DATASET")
    demo_actions: str = option("auto", "demo action: reached (the latent the tool reached, the paper's), "
                                       "recorded (the recorded command), or auto (recorded for scripted demos and "
                                       "real episodes that logged /hingelab/action, reached for the heuristic's)",
                               choices=DEMO_ACTIONS)
    demo_lookahead: int = option(1, "the reached latent this many steps after the step (1: the step's own, the "
                                    "paper's)")

    def prior_checks(self) -> dict[str, bool]:
        least = 1
        if self.prior_objects == "all":  # the pick table's sets (sim.objects loads MuJoCo): only for them
            from hingelab.sim.objects import PICK_SETS

            least = len(PICK_SETS)
        return {"prior_episodes": self.prior_episodes >= least,
                "prior_objects": self.prior_objects in PRIOR_OBJECTS, "demo_actions": self.demo_actions in DEMO_ACTIONS,
                "prior_source": self.prior_source in PRIOR_SOURCES, "demo_lookahead": self.demo_lookahead >= 1,
                "prior_action_noise": self.prior_action_noise >= 0}

    def check_prior(self) -> None:
        """The combinations of prior flags that contradict each other: one-line errors."""
        if self.prior_action_noise and (self.prior_source == "heuristic" or self.from_datasets or not self.prior):
            raise ConfigError("--prior-action-noise is noise on the scripted demonstrator's actions as the run "
                              "generates its prior: drop it, or drop --from / --no-prior / --prior-source heuristic")
        if not self.prior and self.from_datasets:
            raise ConfigError("--no-prior trains without demonstrations: drop --from")


def base_observation_form(base: str) -> dict:
    """ToolPick-v0's observation arguments (``observe_extent``, ``tool_position``) the phase clone a learner starts
    from (``--base shipped`` or a checkpoint's path) was trained with; {} where it cannot be read here (the run then
    says what is wrong with it). Learners over a base observe as it was trained unless ``--env-kwargs`` says."""
    from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL, observation_form  # torch: when a config is checked
    from hingelab.policies.phase_clone import PhaseClone

    try:
        return observation_form(PhaseClone.load(SHIPPED_HIGH_LEVEL if base == "shipped" else base))
    except ConfigError:
        return {}


__all__ = ["RunSettings", "PickTask", "PickReward", "PriorDemos", "DEMO_ACTIONS", "base_observation_form"]
