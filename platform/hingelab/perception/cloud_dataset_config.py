"""What ``hingelab generate clouds`` makes (``hingelab.perception.synthetic_dataset`` makes it): a plain
dataclass, so the command's flags take their defaults without loading the simulator."""

from __future__ import annotations

import math
from dataclasses import dataclass

from hingelab.errors import ConfigError


@dataclass(frozen=True)
class CloudDatasetConfig:
    """What ``hingelab generate clouds`` makes (recorded in the dataset card)."""

    n_clouds: int = 10_000  # clouds in the dataset
    clouds_per_episode: int = 100  # clouds per episode file
    seed: int = 0  # base seed; episode k uses seed + k
    noise_std_m: float = 0.005  # per-point Gaussian noise, metres (paper: 5 mm for the encoder)
    noise_std_max_m: float | None = None  # if set: noise per cloud uniform in [noise_std_m, this]
    removal_fraction: float = 0.2  # occlusion: fraction of points removed
    max_angle_deg: float = 30.0  # pose variation about the nominal in-hand pose, per Euler angle
    max_offset_m: float = 0.02  # pose variation, per axis, metres

    def __post_init__(self):
        if self.n_clouds < 1 or self.clouds_per_episode < 1:
            raise ConfigError(f"n_clouds and clouds_per_episode must be >= 1, got {self.n_clouds}, "
                              f"{self.clouds_per_episode}")
        if not 0.0 <= self.removal_fraction < 1.0:  # (NaN fails these comparisons too)
            raise ConfigError(f"removal_fraction must be in [0, 1), not {self.removal_fraction}")
        for name in ("noise_std_m", "noise_std_max_m", "max_angle_deg", "max_offset_m"):
            value = getattr(self, name)
            if value is not None and not 0.0 <= value < math.inf:
                raise ConfigError(f"{name} must be a finite number >= 0, not {value}")
        if self.noise_std_max_m is not None and self.noise_std_max_m < self.noise_std_m:
            raise ConfigError(f"noise_std_max_m ({self.noise_std_max_m}) must be >= noise_std_m "
                              f"({self.noise_std_m})")

    @property
    def noise_range_m(self) -> tuple[float, float]:
        """(lowest, highest) per-cloud noise level, metres."""
        return self.noise_std_m, self.noise_std_m if self.noise_std_max_m is None else self.noise_std_max_m

    @property
    def n_episodes(self) -> int:
        return -(-self.n_clouds // self.clouds_per_episode)
