"""Every hyperparameter of a low-level run (``hingelab train low``), saved with the run.

One frozen dataclass on ``SACTrainConfig``: its fields are the command's flags, ``RUNDIR/config.json``
stores it with the code version and seed, and ``--resume`` reads it back (a resumed run keeps
its config). Defaults follow the paper where it speaks (SAC, 2 x 256 ReLU, the effort reward,
20 Hz, domain randomization) and SAC's usual values where it does not.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from hingelab.errors import ConfigError
from hingelab.learners.sac.config import SACTrainConfig
from hingelab.tasks import TOOL_SHAPE_ID as ENV_ID
from hingelab.training.run_config import option

GOAL_SAMPLINGS = ("reachable", "reachable_open", "reachable_closed", "normal")


def opening_band(text: str) -> tuple[float, float]:
    """'0:0.10' -> (0.0, 0.1), for --goal-openings."""
    try:
        low, high = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not LOW:HIGH in rad (e.g. 0:0.10)") from None
    if not low < high:
        raise argparse.ArgumentTypeError(f"{text!r}: LOW must be below HIGH")
    return low, high


@dataclass(frozen=True)
class LowLevelTrainConfig(SACTrainConfig):
    use_effort: bool = option(True, "drop the effort reward (the paper's ablation)", flag="--no-effort", negate=True)
    effort_weight: float = option(50.0, "c2: weight of the tool-motion part of the effort reward, per m of mean "
                                        "tool-point displacement per step (larger holds the tool stiller)",
                                  metavar="C2")
    drift_weight: float = option(0.0, "c4: a training-only penalty on the tool's true drift in the hand "
                                      "(privileged state), per m beyond 5 mm, per step (0: off, the paper's "
                                      "reward; e.g. 60 makes 1 cm of drift cost 0.3 per step)", metavar="C4")
    her: bool = option(False, "HER relabelling (future strategy, 4 goals)")
    goal_sampling: str = option("reachable", "training goals: latents of reachable openings, the same with half of "
                                             "them in the open 40%% (reachable_open) or the closed 25%% "
                                             "(reachable_closed) of the range, or N(0, I) as in the paper",
                                flag="--goals", choices=GOAL_SAMPLINGS)
    goal_openings: tuple | None = option(None, "reachable training goals from this band of openings only (rad, "
                                               "e.g. 0:0.10): an expert for the band, to combine with others by "
                                               "hingelab compose low", parse=opening_band, metavar="LOW:HIGH")
    eval_goals_per_region: int = option(4, "held-out goals per third of the reachable opening range",
                                        flag="--eval-goals")
    offline_updates: int = option(0, "train from the --from datasets alone for this many updates (no env "
                                      "rollouts)", flag="--offline", metavar="UPDATES")
    init_from: str = option("", "start from a trained low-level policy (a .zip, run folder or checkpoints/step_* "
                                "folder): its actor, critics, optimizers and entropy coefficient; the replay buffer "
                                "starts empty (or from --from). Fine-tuning, e.g. with other --goals",
                            metavar="CHECKPOINT")

    kind = "low-level"
    env_id = ENV_ID
    train_source = "low_level_training"
    action_level = "low"

    def __post_init__(self):
        self.check({**self.sac_checks(), "offline_updates": self.offline_updates >= 0,
                    "eval_goals_per_region": self.eval_goals_per_region >= 1,
                    "goal_sampling": self.goal_sampling in GOAL_SAMPLINGS,
                    "effort_weight": self.effort_weight >= 0, "drift_weight": self.drift_weight >= 0})
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
            raise ConfigError("learning from demonstrations (--bc-weight, --bc-pretrain) needs them: "
                              "add --from DATASET")
        if self.init_from and self.offline_updates:
            raise ConfigError("--init-from starts online training from a policy; --offline trains from datasets: "
                              "drop one")
        if self.learns_from_demonstrations and (self.algorithm != "fast_sac" or self.her):
            raise ConfigError("--bc-weight and --bc-pretrain work with --algorithm fast_sac and without --her")

    def env_arguments(self) -> dict:
        """Keyword arguments of ``gymnasium.make(ENV_ID, ...)`` for this run."""
        return {"use_effort": self.use_effort, "effort_weight": self.effort_weight, "drift_weight": self.drift_weight,
                "goal_sampling": self.goal_sampling, "randomize": self.randomize,
                "max_episode_steps": self.max_episode_steps,
                **({"goal_openings": self.goal_openings} if self.goal_openings is not None else {}), **self.env_kwargs}

    def recording_metadata(self) -> dict:
        return {"use_effort": str(self.use_effort)}
