"""The report's tables, from the episode table (``episode_table.py``) with pandas.

- ``success_rates(episodes, by, verdict=False)``: episodes, successes, rate and its Wilson
  95% interval per group (``by``: ``source``, ``object``, ``object_size``, or several);
  ``verdict=True`` adds the column ``verdict``: what ``success`` counts in the group (the
  episode table's ``verdict``, several joined by "; " if the group mixes them).
- ``attempt_rates(episodes, ks)``: the paper's real-robot table: per source and object,
  the share of **trials** that succeeded at the first attempt and within k attempts.
  A trial is the episodes sharing (dataset, source, object, object_size, seed): one
  episode that retries inside itself records the attempt it ended on (the heuristic,
  ``attempt`` fact), or one episode per attempt with ``attempt`` = 1, 2, ...; both count
  the same way: a trial succeeds within k attempts if one of its episodes has
  ``success`` and ``attempt <= k``.
- ``length_return_stats(episodes)``: distribution of length (steps) and return per source.
- ``failure_reasons(episodes)``: failed episodes per source and recorded reason
  (``(not recorded)`` where a source gives none).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from hingelab.analysis.wilson import wilson_interval

TRIAL_KEYS = ["dataset", "source", "object", "object_size", "seed"]


def _with_interval(table: pd.DataFrame, successes: str, trials: str, prefix: str) -> pd.DataFrame:
    low, high = wilson_interval(table[successes].to_numpy(), table[trials].to_numpy())
    table[f"{prefix}rate"] = table[successes] / table[trials]
    table[f"{prefix}ci_low"] = low
    table[f"{prefix}ci_high"] = high
    return table


def _size_labels(episodes: pd.DataFrame) -> pd.DataFrame:
    """object_size as a group label: millimetres rounded to 0.1, ``(unknown)`` for NaN."""
    sizes = episodes["object_size"]
    label = (sizes * 1000).round(1).map(lambda mm: f"{mm:g} mm").where(sizes.notna(), "(unknown)")
    return episodes.assign(object_size=label)


def _joined(values: pd.Series) -> str:
    return "; ".join(sorted(set(values.astype(str))))


def success_rates(episodes: pd.DataFrame, by: str | Sequence[str], verdict: bool = False) -> pd.DataFrame:
    """Per group: episodes, successes, success_rate, ci_low, ci_high (Wilson 95%); with ``verdict``,
    a ``verdict`` column after the group keys (what success counts there)."""
    by = [by] if isinstance(by, str) else list(by)
    frame = _size_labels(episodes) if "object_size" in by else episodes
    grouped = frame.groupby(by, sort=True, dropna=False)
    table = grouped.agg(episodes=("success", "size"), successes=("success", "sum")).reset_index()
    table["successes"] = table["successes"].astype("int64")
    if verdict and "verdict" in frame.columns:
        table.insert(len(by), "verdict", grouped["verdict"].agg(_joined).to_numpy())
    return _with_interval(table, "successes", "episodes", "success_")


def overall_success(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row over all episodes: episodes, successes, rate and interval, and what success counts."""
    return success_rates(episodes.assign(all="all"), "all", verdict=True)


def attempt_rates(episodes: pd.DataFrame, ks: Sequence[int] = (1, 2, 3)) -> pd.DataFrame:
    """Per source and object: trials, then for each k: successes and rate within k attempts (Wilson 95%).

    Column prefixes: ``first_attempt_`` for k = 1, ``within_{k}_`` for the others, and
    ``any_attempt_`` for success at any attempt.
    """
    frame = episodes.copy()
    frame["object_size"] = frame["object_size"].fillna(-1.0)  # NaN keys would drop trials
    limits = {("first_attempt" if k == 1 else f"within_{k}"): k for k in sorted(set(ks))}
    limits["any_attempt"] = np.iinfo(np.int64).max
    for name, k in limits.items():
        frame[name] = frame["success"] & (frame["attempt"] <= k)
    trials = frame.groupby(TRIAL_KEYS, sort=True)[list(limits)].any().reset_index()
    table = trials.groupby(["source", "object"], sort=True).agg(
        trials=("seed", "size"), **{f"{name}_successes": (name, "sum") for name in limits}).reset_index()
    for name in limits:
        table[f"{name}_successes"] = table[f"{name}_successes"].astype("int64")
        table = _with_interval(table, f"{name}_successes", "trials", f"{name}_")
    return table


def length_return_stats(episodes: pd.DataFrame, by: str | Sequence[str] = "source") -> pd.DataFrame:
    """Per group: mean, std, median, min, max of length (steps) and return."""
    by = [by] if isinstance(by, str) else list(by)
    frame = episodes.assign(length=episodes["length"].astype("float64"),
                            **{"return": episodes["return"].astype("float64")})
    stats = frame.groupby(by, sort=True)[["length", "return"]].agg(["mean", "std", "median", "min", "max"])
    stats.columns = [f"{column}_{stat}" for column, stat in stats.columns]
    counts = frame.groupby(by, sort=True).size().rename("episodes")
    return pd.concat([counts, stats], axis=1).reset_index()


def failure_reasons(episodes: pd.DataFrame) -> pd.DataFrame:
    """Failed episodes per source and reason, with the share of that source's failures."""
    failed = episodes[~episodes["success"]]
    reasons = failed["failure_reason"].fillna("").replace("", "(not recorded)")
    table = failed.assign(failure_reason=reasons).groupby(["source", "failure_reason"], sort=True).size()
    table = table.rename("episodes").reset_index()
    table["share_of_failures"] = table["episodes"] / table.groupby("source")["episodes"].transform("sum")
    return table


__all__ = ["success_rates", "overall_success", "attempt_rates", "length_return_stats", "failure_reasons",
           "TRIAL_KEYS"]
