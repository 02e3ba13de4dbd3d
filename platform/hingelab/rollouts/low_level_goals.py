"""The held-out evaluation goals of a low-level run (ToolShape-v0); the rollout envs are
``hingelab.training.envs``'s."""

from __future__ import annotations

import numpy as np

from hingelab.seeds import held_out_goal_seed

# ---------------------------------------------------------------------------- evaluation goals
REGIONS = ("closed", "middle", "open")  # thirds of the reachable opening range


def evaluation_goals(calibration, reachable_range: tuple[float, float], per_region: int) -> list[dict]:
    """Fixed held-out goals: ``per_region`` openings evenly inside each third of the reachable range.

    Returns dicts with ``region``, ``opening_rad``, ``z_goal`` (2,) and the episode ``seed``.
    """
    low, high = reachable_range
    edges = np.linspace(low, high, len(REGIONS) + 1)
    goals = []
    for r, region in enumerate(REGIONS):
        # centres of per_region equal slices of the third: never on a region edge
        step = (edges[r + 1] - edges[r]) / per_region
        for j in range(per_region):
            opening = float(edges[r] + (j + 0.5) * step)
            goals.append({"region": region, "opening_rad": opening,
                          "z_goal": np.asarray(calibration.z_for_opening(opening), float),
                          "seed": held_out_goal_seed(len(goals))})
    return goals


def region_of(opening: float, reachable_range: tuple[float, float]) -> str:
    low, high = reachable_range
    third = (high - low) / len(REGIONS)
    index = int(np.clip((opening - low) // third, 0, len(REGIONS) - 1))
    return REGIONS[index]
