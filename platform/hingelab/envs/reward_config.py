"""The reward settings of the tasks (``hingelab.envs.rewards`` computes the rewards; the module doc there says
what each term means): plain dataclasses, so that a training config and its flags need no physics."""

from __future__ import annotations

from dataclasses import dataclass

from hingelab.errors import ConfigError


@dataclass(frozen=True)
class LowLevelRewardConfig:
    c1: float = 5.0  # 1/latent unit: goal term exp(-c1 d); d = 0.1 -> 0.61
    c2: float = 50.0  # 1/m: a mean point displacement of 1 mm per step costs 0.05
    c3: float = 0.05  # s/rad: fingers at 1 rad/s cost 0.05
    c4: float = 0.0  # 1/m: tool drift beyond drift_free_m costs c4 per m per step (0: off, the paper's reward)
    drift_free_m: float = 0.005  # drift up to this is free: the grasp settles by a few mm on its own
    use_effort: bool = True  # the paper's ablation switches the effort term off (the drift term with it)
    control_dt: float = 0.05


HIGH_LEVEL_REWARD_MODES = ("absorbing", "paper")
#: the reward config of recordings that do not name theirs: every one made before the modes existed
LEGACY_MODE = "paper"


@dataclass(frozen=True)
class HighLevelRewardConfig:
    c_h1: float = 10.0  # sparse success bonus
    c_h2: float = 20.0  # 1/m: tool-object closeness
    c_h3: float = 1.0
    c_h4: float = 20.0  # 1/m: object-target closeness
    c_h5: float = 1.0  # penalty
    far: float = 0.20  # m (paper: 20 cm)
    success_radius: float = 0.01  # m (paper: 1 cm)
    mode: str = "absorbing"  # or "paper" (module doc)
    gamma: float = 0.98  # the learner's discount: the absorbing term's (unused by mode "paper")

    def __post_init__(self):
        if self.mode not in HIGH_LEVEL_REWARD_MODES:
            raise ConfigError(f"unknown high-level reward mode {self.mode!r}; choose one of "
                              f"{', '.join(HIGH_LEVEL_REWARD_MODES)}")
        if not 0.0 <= self.gamma < 1.0:
            raise ConfigError(f"the reward's discount gamma must be in [0, 1), not {self.gamma!r}")

    @property
    def max_step_reward(self) -> float:
        """R_max: the best reward of a step that is not a success (tool on the object, object at the target)."""
        return 1.0 + self.c_h3

    @property
    def absorbing_bonus(self) -> float:
        """What a success step adds in mode "absorbing": gamma R_max / (1 - gamma); 0 in mode "paper"."""
        if self.mode != "absorbing":
            return 0.0
        return self.gamma * self.max_step_reward / (1.0 - self.gamma)
