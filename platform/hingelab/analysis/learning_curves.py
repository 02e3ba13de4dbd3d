"""Learning curves from training run folders: success rate and return against environment steps.

The run-folder metrics format (what ``hingelab train`` writes, one row per evaluation):

    RUNDIR/metrics.csv          columns (header required, more columns allowed):
        env_steps     int    environment steps taken by the learner so far
        seed          int    the training seed of this row's run
        success_rate  float  share of evaluation episodes that succeeded, 0..1
        return        float  mean evaluation return
    RUNDIR/run.json             optional: {"name": "..."}; the curve's label (default: RUNDIR's name)

A sweep folder (``hingelab sweep --out DIR``: ``DIR/sweep.csv`` and one run folder per trial, each
labelled with its condition) given as a run folder stands for its trials (``expand_sweeps``), so
its curves are grouped by condition, one seed per trial.

A run trained with several seeds either writes all of them into one ``metrics.csv``
(the ``seed`` column tells them apart) or one subfolder per seed, each with its own
``metrics.csv`` (``RUNDIR/*/metrics.csv``; a missing ``seed`` column is then taken from
the subfolder's position). Curves: per run and env_steps, the mean over seeds and a band
of +- one standard deviation (``*_std``; 0 with one seed), and the seed count. Seeds
are expected to evaluate at the same env_steps (a fixed evaluation interval).

``success_rate`` is the run's one success verdict (``hingelab train low``: settled over the
last 0.5 s, the env's ``is_success``; its secondary one-frame verdict is
``last_step_success_rate``). ``hingelab train low`` wrote ``metrics.csv`` before episode
schema 2 with ``success_rate`` = the last step's verdict and ``settled_success_rate`` = the
settled one; such a file (``settled_success_rate`` present, ``last_step_success_rate``
absent) is read under today's names (``OLD_TRAIN_LOW_COLUMNS``), so old and new runs plot
the same verdict.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pandas as pd

from hingelab.analysis.episode_table import ReportInputError

METRICS_FILE = "metrics.csv"
RUN_FILE = "run.json"
REQUIRED_COLUMNS = ("env_steps", "seed", "success_rate", "return")
CURVE_METRICS = ("success_rate", "return")
# drawn too for the runs that record them (hingelab train low does); NaN for the others
OPTIONAL_CURVE_METRICS = ("last_step_success_rate", "final_latent_distance", "tool_drift_mm_mean",
                          "first_attempt_success_rate")  # the last: hingelab train high and flat
# hingelab train low's metrics.csv before schema 2 -> today's names (the settled verdict is success)
OLD_TRAIN_LOW_COLUMNS = {
    "success_rate": "last_step_success_rate", "settled_success_rate": "success_rate",
    "success_under_1cm": "last_step_success_under_1cm", "settled_success_under_1cm": "success_under_1cm",
    "rollout_success_rate": "last_step_rollout_success_rate",
    **{f"success_{region}": f"last_step_success_{region}" for region in ("closed", "middle", "open")},
}


def old_metrics_renames(columns) -> dict[str, str]:
    """``OLD_TRAIN_LOW_COLUMNS`` if ``columns`` are an old ``hingelab train low`` metrics.csv's
    (``settled_success_rate`` and no ``last_step_success_rate``), else no renames."""
    columns = set(columns)
    old = "settled_success_rate" in columns and "last_step_success_rate" not in columns
    return OLD_TRAIN_LOW_COLUMNS if old else {}


def upgrade_metrics(frame: pd.DataFrame) -> pd.DataFrame:
    """A metrics table under today's names: an old ``hingelab train low`` file's verdicts renamed
    (``OLD_TRAIN_LOW_COLUMNS``); any other table as it is."""
    return frame.rename(columns=old_metrics_renames(frame.columns))


def run_name(run_dir: Path) -> str:
    run_file = run_dir / RUN_FILE
    if run_file.exists():
        try:
            return str(json.loads(run_file.read_text()).get("name") or run_dir.name)
        except (OSError, ValueError):
            pass
    return run_dir.name


def load_run_metrics(run_dir) -> pd.DataFrame:
    """All metrics rows of one run folder, with a ``run`` column (see the module docstring)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ReportInputError(f"run folder {run_dir} does not exist; give a training run folder "
                               f"(it holds {METRICS_FILE})")
    files = [run_dir / METRICS_FILE] if (run_dir / METRICS_FILE).exists() else sorted(run_dir.glob(f"*/{METRICS_FILE}"))
    if not files:
        raise ReportInputError(f"{run_dir} has no {METRICS_FILE} (nor */{METRICS_FILE}); "
                               f"a run folder records columns {', '.join(REQUIRED_COLUMNS)}")
    frames = []
    for position, path in enumerate(files):
        frame = upgrade_metrics(pd.read_csv(path))
        if "seed" not in frame.columns and path.parent != run_dir:
            frame["seed"] = position
        missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
        if missing:
            raise ReportInputError(f"{path} lacks the column(s) {', '.join(missing)}; "
                                   f"{METRICS_FILE} needs {', '.join(REQUIRED_COLUMNS)}")
        frames.append(frame)
    metrics = pd.concat(frames, ignore_index=True)
    metrics.insert(0, "run", run_name(run_dir))
    return metrics


def learning_curves(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per run and env_steps: seeds, and mean and std over seeds of success_rate and return (and of
    the OPTIONAL_CURVE_METRICS that any run records; NaN for runs without them)."""
    grouped = metrics.groupby(["run", "env_steps"], sort=True)
    table = grouped["seed"].nunique().rename("seeds").to_frame()
    optional = [m for m in OPTIONAL_CURVE_METRICS if m in metrics.columns and metrics[m].notna().any()]
    for metric in (*CURVE_METRICS, *optional):
        table[f"{metric}_mean"] = grouped[metric].mean()
        table[f"{metric}_std"] = grouped[metric].std(ddof=1).fillna(0.0)
    return table.reset_index()


SEED_CURVE_METRICS = ("success_rate", "first_attempt_success_rate", "return")


def load_seed_curves(run_dirs) -> pd.DataFrame:
    """Per run, seed and env_steps: the success rates of each seed (the curves under the mean)."""
    run_dirs = list(run_dirs or [])
    if not run_dirs:
        return pd.DataFrame(columns=["run", "seed", "env_steps", "success_rate"])
    metrics = pd.concat([load_run_metrics(d) for d in run_dirs], ignore_index=True)
    columns = ["run", "seed", "env_steps"] + [m for m in SEED_CURVE_METRICS if m in metrics.columns]
    return metrics[columns].sort_values(["run", "seed", "env_steps"]).reset_index(drop=True)


SWEEP_CSV = "sweep.csv"  # hingelab.sweeps.runner's table of trials (not imported: analysis needs no Ray)


def expand_sweeps(run_dirs) -> list[Path]:
    """``run_dirs`` with every sweep folder (a ``sweep.csv``, no ``metrics.csv`` of its own) replaced by
    its trials' run folders that have evaluations, in the sweep's order."""
    out = []
    for run_dir in map(Path, run_dirs or []):
        if (run_dir / SWEEP_CSV).exists() and not (run_dir / METRICS_FILE).exists():
            with open(run_dir / SWEEP_CSV, newline="") as f:
                trials = [run_dir / row["trial"] for row in csv.DictReader(f)]
            found = [t for t in trials if (t / METRICS_FILE).exists()]
            if not found:
                raise ReportInputError(f"the sweep {run_dir} has no trial with {METRICS_FILE} yet")
            out += found
        else:
            out.append(run_dir)
    return out


def final_success(seeds: pd.DataFrame, confidence: float = 0.95) -> pd.DataFrame:
    """Per run label (a sweep's condition): the last evaluation's success over its seeds: mean, std and a
    Student-t ``confidence`` interval across seeds (the seeds are the samples; clipped to [0, 1]; NaN with
    one seed), and the same for first-attempt success where recorded. ``seeds``: ``seed_summary``'s table."""
    from scipy import stats  # about 1 s to import; training and every CLI command import this module without needing it

    rows = []
    for run, part in seeds.groupby("run", sort=True):
        row = {"run": run, "seeds": int(len(part)), "last_env_steps_min": int(part["last_env_steps"].min())}
        for column, name in (("last_success_rate", "success_rate"),
                             ("last_first_attempt_success_rate", "first_attempt_success_rate")):
            if column not in part.columns or part[column].isna().all():
                continue
            values = part[column].dropna().to_numpy(float)
            n, mean = len(values), float(values.mean())
            std = float(values.std(ddof=1)) if n > 1 else float("nan")
            half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * std / np.sqrt(n)) if n > 1 else float("nan")
            row |= {f"{name}_mean": mean, f"{name}_std": std, f"{name}_ci_low": max(0.0, mean - half),
                    f"{name}_ci_high": min(1.0, mean + half)}
            if n < 2:
                row[f"{name}_ci_low"] = row[f"{name}_ci_high"] = float("nan")
        rows.append(row)
    return pd.DataFrame(rows)


REACH_LEVEL = 0.5  # the success rate whose first crossing the seed table reports (the paper's speed-up claim)


def seed_summary(seeds: pd.DataFrame, level: float = REACH_LEVEL) -> pd.DataFrame:
    """Per run and seed: the first env_steps at which success_rate reached ``level`` (NaN: never); the
    first evaluation's success (the start: for a fine-tune, its prior), the lowest, how far the lowest fell
    below the start (0 when never) and the last minus the start (whether a run keeps and then beats its
    prior); the last evaluation's env_steps and success (and first-attempt success where recorded)."""
    rows = []
    for (run, seed), part in seeds.groupby(["run", "seed"], sort=True):
        part = part.sort_values("env_steps")
        reached = part.loc[part["success_rate"] >= level, "env_steps"]
        first, last = part.iloc[0], part.iloc[-1]
        start, lowest = float(first["success_rate"]), float(part["success_rate"].min())
        row = {"run": run, "seed": seed, f"env_steps_to_{level:g}": float(reached.iloc[0]) if len(reached) else
               float("nan"), "start_success_rate": start, "lowest_success_rate": lowest,
               "largest_drop_below_start": max(0.0, start - lowest),
               "last_minus_start": float(last["success_rate"]) - start,
               "last_env_steps": int(last["env_steps"]), "last_success_rate": float(last["success_rate"])}
        if "first_attempt_success_rate" in part.columns:
            row["last_first_attempt_success_rate"] = float(last["first_attempt_success_rate"])
        rows.append(row)
    return pd.DataFrame(rows)


def load_learning_curves(run_dirs) -> pd.DataFrame:
    """Curves of several run folders (empty frame for no runs)."""
    run_dirs = list(run_dirs or [])
    if not run_dirs:
        return pd.DataFrame(columns=["run", "env_steps", "seeds"]
                            + [f"{m}_{s}" for m in CURVE_METRICS for s in ("mean", "std")])
    return learning_curves(pd.concat([load_run_metrics(d) for d in run_dirs], ignore_index=True))


__all__ = ["expand_sweeps", "final_success", "SWEEP_CSV", "REACH_LEVEL", "seed_summary", "SEED_CURVE_METRICS",
           "load_seed_curves", "OPTIONAL_CURVE_METRICS", "OLD_TRAIN_LOW_COLUMNS", "old_metrics_renames",
           "upgrade_metrics", "load_run_metrics", "learning_curves", "load_learning_curves", "METRICS_FILE",
           "REQUIRED_COLUMNS"]
