"""What ``hingelab generate heuristic`` runs: a plain dataclass (``hingelab.rollouts.heuristic_demos`` runs it),
so the command's flags take their defaults without loading the simulator."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class HeuristicRunConfig:
    """What ``hingelab generate heuristic`` runs (saved in the dataset card)."""

    episodes: int = 100
    object: str = "sphere"  # a shape name or mesh:PATH (an STL, OBJ or PLY file)
    size: float = 0.02  # m, the object's width (sphere: diameter)
    mass: float = 0.01  # kg
    seed: int = 0
    workers: int = 1
    randomize: bool = True
    max_episode_steps: int = 200
    object_noise: str = "gaussian"  # ToolPick-v0's: or "fitted:NAME", the camera's error on the observation
    object_noise_model: str | None = None  # the fitted model's file (None: the default one)
