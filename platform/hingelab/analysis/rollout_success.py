"""Success of a training run's own rollouts early on: the episodes a dataset holds in the order they were
written, the ones that ended within its first ``first_steps`` env steps, and how many of them succeeded.

A training run records every rollout into its dataset (``RUNDIR/dataset``) as it ends, so the write order
(the files' modification times) is the run's order and the running sum of lengths its env steps (one env;
with several, the steps of all of them). Issue 42's reading of "the prior's rollouts succeed from the
start" is this table's ``first_rate`` at 5,000 steps.
"""

from __future__ import annotations

import pandas as pd

from hingelab.analysis.wilson import wilson_interval

FIRST_STEPS = 5000
COLUMNS = ["dataset", "dataset_path", "first_steps", "first_episodes", "first_successes", "first_rate",
           "first_ci_low", "first_ci_high", "episodes", "successes", "rate"]


def early_rollout_success(episodes: pd.DataFrame, first_steps: int = FIRST_STEPS) -> pd.DataFrame:
    """Per dataset of ``episodes`` (the report's episode table: ``dataset``, ``dataset_path``, ``length``,
    ``success``, ``mtime_ns``): its episodes in write order, those whose steps end within ``first_steps``,
    their successes with a Wilson 95% interval, and the whole dataset's."""
    rows = []
    for path, group in episodes.groupby("dataset_path", sort=False):
        ordered = group.sort_values(["mtime_ns", "file"] if "file" in group else ["mtime_ns"], kind="stable")
        ends = ordered["length"].astype(int).cumsum()
        success = ordered["success"].astype(bool)
        first = success[(ends <= first_steps).to_numpy()]
        low, high = wilson_interval(int(first.sum()), len(first))
        rows.append({"dataset": ordered["dataset"].iloc[0], "dataset_path": path, "first_steps": first_steps,
                     "first_episodes": len(first), "first_successes": int(first.sum()),
                     "first_rate": float(first.mean()) if len(first) else float("nan"),
                     "first_ci_low": float(low), "first_ci_high": float(high), "episodes": len(success),
                     "successes": int(success.sum()), "rate": float(success.mean()) if len(success) else float("nan")})
    return pd.DataFrame(rows, columns=COLUMNS)


__all__ = ["FIRST_STEPS", "early_rollout_success"]
