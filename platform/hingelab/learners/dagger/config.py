"""The settings of a DAgger run over the phase clone (``hingelab train high --learner dagger``), saved with the run."""

from __future__ import annotations

from dataclasses import dataclass

from hingelab.errors import ConfigError
from hingelab.learners.phase_clone.config import PhaseCloneConfig
from hingelab.training.config_parts import base_observation_form
from hingelab.training.run_config import option

BASES = ("fit", "shipped")  # or a phase-clone checkpoint's path
ROLLOUT_OBJECTS = ("all", "run")


@dataclass(frozen=True)
class DaggerConfig(PhaseCloneConfig):
    # the held-out evaluation of each round on the sets the rounds roll out on (one of the 12 per episode), not on
    # one sphere, where every clone here picks everything
    object: str = option("family:picksets", "the object of the held-out evaluations (and of the rollouts with "
                                            "--rollout-objects run): sphere, cube, cylinder, tetrahedron, mesh:PATH "
                                            "or family:NAME[:SEED] (a new object each episode, --size its cap)")
    base: str = option("fit", "the clone to start from: fit (fitted first on the run's privileged prior by the phase "
                              "clone's recipe, the --net-arch and --clone-* flags), shipped "
                              "(assets/checkpoints/high_level.zip) or a phase-clone checkpoint (its prior should be "
                              "the --from demos, which every round learns from again)", metavar="fit|shipped|CKPT")
    dagger_rounds: int = option(3, "rounds of rollouts by the clone, labelled by the demonstrator, each followed by "
                                   "a fit on all demos and labelled steps so far", metavar="ROUNDS")
    dagger_episodes: int = option(120, "rollout episodes per round: shared evenly over the pick table's 12 sets "
                                       "(--rollout-objects all) or all of --object (run)", metavar="EPISODES")
    rollout_objects: str = option("all", "the objects of the rounds' rollouts: all (the pick table's 12 sets) or run "
                                         "(--object and --size)", choices=ROLLOUT_OBJECTS)
    dagger_updates: int = option(5_000, "Adam updates of each member per round, going on from the last round's nets",
                                 metavar="UPDATES")
    dagger_learning_rate: float = option(3e-4, "Adam's learning rate of a round's fit (cosine decay to 0)")
    demonstrator_share: float = option(0.0, "chance, each step of a rollout, that the demonstrator's action is the "
                                            "one executed (DAgger's beta; 0: the clone drives and the demonstrator "
                                            "only labels)")

    kind = "dagger"

    def __post_init__(self):
        super().__post_init__()
        self.check({"dagger_rounds": self.dagger_rounds >= 1, "dagger_episodes": self.dagger_episodes >= 1,
                    "dagger_updates": self.dagger_updates >= 1, "dagger_learning_rate": self.dagger_learning_rate > 0,
                    "demonstrator_share": 0 <= self.demonstrator_share <= 1})
        if self.base != "fit":  # observe as the base was trained to (its prior too), where --env-kwargs does not say
            object.__setattr__(self, "env_kwargs", {**base_observation_form(self.base), **self.env_kwargs})
        if self.prior_source != "scripted" and not self.from_datasets:
            raise ConfigError("--learner dagger labels the clone's rollouts with the scripted demonstrator: its "
                              "prior must be scripted too (--prior-source scripted)")
