"""``build_report(datasets, runs, out)``: the success-rate and learning-curve report.

Writes into ``out`` (created if needed; files of an earlier report are replaced):

    report.md, report.html         the tables and plots, for reading
    report.json                    where the numbers came from: datasets (path, card name,
                                   config hash, episodes), run folders, code version, time
    episodes.csv                   the episode table every number is computed from
    overall.csv, success_by_source.csv, success_by_dataset.csv, success_by_object.csv, success_by_size.csv,
    attempts.csv, lengths_returns.csv, failure_reasons.csv, learning_curves.csv (with runs)
    *.png                          the plots beside them

Every number is recomputed from the datasets' episode files (their index) and the run
folders' ``metrics.csv``: rerun the same command to refresh a report.

Success is each episode's recorded ``success``: its task's one verdict, the one the env's
info, the demo and ``eval`` count. The report says which verdict that is, per
dataset (a line at the top, and the ``verdict`` column of the overall, by-source and
by-dataset tables): the episodes' ``success_verdict`` (e.g. settled over the last 0.5 s for
ToolShape-v0), or for episodes written before schema 2, what their task recorded then
(ToolShape-v0: the last step).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from hingelab.analysis import plots
from hingelab.analysis.documents import Section, write_documents
from hingelab.analysis.episode_table import load_episode_table
from hingelab.analysis.learning_curves import (
    METRICS_FILE,
    REACH_LEVEL,
    expand_sweeps,
    final_success,
    load_learning_curves,
    load_seed_curves,
    seed_summary,
)
from hingelab.analysis.rollout_success import FIRST_STEPS, early_rollout_success
from hingelab.analysis.success_tables import (
    attempt_rates,
    failure_reasons,
    length_return_stats,
    overall_success,
    success_rates,
)
from hingelab.json_text import strict_dumps
from hingelab.provenance import code_version


@dataclass
class Report:
    """A written report: its folder, the episode table, every table by name, the files written."""

    out: Path
    episodes: pd.DataFrame
    tables: dict[str, pd.DataFrame]
    files: list[Path] = field(default_factory=list)

    @property
    def html(self) -> Path:
        return self.out / "report.html"

    @property
    def markdown(self) -> Path:
        return self.out / "report.md"


def compute_tables(episodes: pd.DataFrame, curves: pd.DataFrame, attempts_k=(1, 2, 3),
                   seed_curves: pd.DataFrame | None = None) -> dict[str, pd.DataFrame]:
    """Every table of the report, by the name of its CSV file (without .csv)."""
    tables = {
        "overall": overall_success(episodes),
        "success_by_source": success_rates(episodes, "source", verdict=True),
        "success_by_dataset": success_rates(episodes, ["dataset", "source"], verdict=True),
        "success_by_object": success_rates(episodes, ["source", "object"]),
        "success_by_size": success_rates(episodes, ["source", "object", "object_size"]),
        "attempts": attempt_rates(episodes, attempts_k),
        "lengths_returns": length_return_stats(episodes, "source"),
        "failure_reasons": failure_reasons(episodes),
    }
    if len(curves):
        tables["learning_curves"] = curves
    if len(curves) and "mtime_ns" in episodes:  # with run folders: their datasets are training rollouts
        tables["early_rollouts"] = early_rollout_success(episodes)
    if seed_curves is not None and len(seed_curves):
        tables["learning_curves_by_seed"] = seed_curves
        tables["seeds"] = seed_summary(seed_curves)
        tables["final_success"] = final_success(tables["seeds"])
    return tables


def _attempt_summary(table: pd.DataFrame) -> pd.DataFrame:
    """The attempts table narrowed to what a reader compares (rates and intervals)."""
    keep = ["source", "object", "trials"] + [c for c in table.columns
                                             if c.endswith(("_rate", "_ci_low", "_ci_high"))]
    return table[keep]


def _sections(tables: dict[str, pd.DataFrame], plot_files: dict[str, str]) -> list[Section]:
    sizes_known = (tables["success_by_size"]["object_size"] != "(unknown)").any()
    sections = [
        Section("Overall", "All episodes of the datasets: success rate with its Wilson 95% interval "
                "(verdict: what success counts; several if the datasets' tasks differ).",
                tables["overall"], "overall.csv"),
        Section("Success rate by source", "Per producing source (heuristic, low_level, high_level, real, ...).",
                tables["success_by_source"], "success_by_source.csv", [plot_files["success_by_source"]]),
        Section("Success rate by dataset", "Per dataset (its card's name): e.g. one evaluation dataset per policy.",
                tables["success_by_dataset"], "success_by_dataset.csv"),
        Section("Success rate by object shape", "Per source and object shape.",
                tables["success_by_object"], "success_by_object.csv", [plot_files["success_by_object"]]),
        Section("Success rate by object size",
                "Per source, shape and size (the episode fact object_size, metres, shown in mm; "
                "'(unknown)' where the source does not record it).",
                tables["success_by_size"], "success_by_size.csv",
                [plot_files["success_by_size"]] if sizes_known else []),
        Section("First attempt and within k attempts",
                "A trial is the episodes of one (dataset, source, object, size, seed); it succeeds within k "
                "attempts if one of them succeeded at attempt <= k. Rates are shares of trials, Wilson 95%.",
                _attempt_summary(tables["attempts"]), "attempts.csv", [plot_files["attempts"]]),
        Section("Episode length and return", "Distribution per source; length in control steps (20 Hz).",
                tables["lengths_returns"], "lengths_returns.csv", [plot_files["lengths"], plot_files["returns"]]),
        Section("Failure reasons", "Failed episodes per source and the reason their source recorded.",
                tables["failure_reasons"], "failure_reasons.csv"),
    ]
    if "learning_curves" in tables:
        sections.append(Section(
            "Learning curves", f"From the run folders' {METRICS_FILE}: mean over seeds, band +- one std. "
            "success_rate is each run's evaluations' success verdict (hingelab train low: settled over the last "
            "0.5 s; its metrics.csv written before schema v2 recorded the last step as success_rate and the "
            "settled verdict as settled_success_rate: read here as last_step_success_rate and success_rate).",
            None, "learning_curves.csv", [plot_files["learning_curves"]]))
    if "early_rollouts" in tables:
        sections.append(Section(
            "Training rollouts early on", f"Per dataset, its episodes in the order written (a training run's "
            f"rollouts: the running sum of lengths is its env steps): those that ended within the first "
            f"{FIRST_STEPS:,} steps and their success (Wilson 95%), then the whole dataset's.",
            tables["early_rollouts"], "early_rollouts.csv"))
    if "learning_curves_by_seed" in tables:
        sections.append(Section(
            "Success of every seed", "Each seed's evaluations (thin) and their mean (thick), per run label: "
            "the runs of one label (run.json) are its seeds. The table: per run and seed, the first evaluation "
            f"whose success rate reached {REACH_LEVEL:g} (empty: none did); the first evaluation (the start: a "
            "fine-tune's prior), the lowest, how far it fell below the start, the last minus the start; and the "
            "last evaluation.",
            tables["seeds"], "seeds.csv", [plot_files["learning_curves_by_seed"]]))
        sections.append(Section(*FINAL_SUCCESS_SECTION, tables["final_success"], "final_success.csv"))
    return sections


FINAL_SUCCESS_SECTION = (
    "Success at the end, across seeds", "Per run label (a sweep's condition): the last evaluation's success "
    "rate of each seed, their mean and std, and a Student-t 95% interval across seeds (the seeds are the "
    "samples; none with one seed); first-attempt success likewise where the runs record it.")


def _plots(out: Path, episodes: pd.DataFrame, tables: dict[str, pd.DataFrame]) -> dict[str, str]:
    written = {
        "success_by_source": plots.grouped_rate_bars(tables["success_by_source"], "source", None,
                                                     out / "success_by_source.png", "success rate by source"),
        "success_by_object": plots.grouped_rate_bars(tables["success_by_object"], "object", "source",
                                                     out / "success_by_object.png", "success rate by object shape"),
        "attempts": plots.attempt_bars(tables["attempts"], out / "attempts.png"),
        "lengths": plots.histograms(episodes, "length", out / "lengths.png", "length (steps)"),
        "returns": plots.histograms(episodes, "return", out / "returns.png", "return"),
    }
    by_size = tables["success_by_size"]
    if (by_size["object_size"] != "(unknown)").any():
        labelled = by_size.assign(shape_size=by_size["object"] + " " + by_size["object_size"])
        written["success_by_size"] = plots.grouped_rate_bars(labelled, "shape_size", "source",
                                                             out / "success_by_size.png", "success rate by object size")
    if "learning_curves" in tables:
        written["learning_curves"] = plots.learning_curve_plot(tables["learning_curves"], out / "learning_curves.png")
    if "learning_curves_by_seed" in tables:
        written["learning_curves_by_seed"] = plots.seed_curve_plot(tables["learning_curves_by_seed"],
                                                                   out / "learning_curves_by_seed.png")
    return {name: path.name for name, path in written.items()}


def verdict_line(episodes: pd.DataFrame) -> str:
    """The report's statement of what success counts, per dataset (and source)."""
    parts = [f"{dataset} ({source}): {'; '.join(sorted(set(part['verdict'])))}"
             for (dataset, source), part in episodes.groupby(["dataset", "source"], sort=True)]
    return "What success counts: " + "; ".join(parts) + "."


def build_report(datasets, out, runs=(), title: str | None = None, attempts_k=(1, 2, 3)) -> Report:
    """Count the datasets (and run folders), write the report into ``out``; see the module docstring."""
    datasets = [Path(d) for d in datasets]
    runs = expand_sweeps(runs)  # a sweep folder: its trials, labelled by condition
    episodes = load_episode_table(datasets)
    curves = load_learning_curves(runs)
    tables = compute_tables(episodes, curves, attempts_k, seed_curves=load_seed_curves(runs))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    episodes.drop(columns=["mtime_ns"], errors="ignore").to_csv(out / "episodes.csv", index=False)
    files.append(out / "episodes.csv")
    for name, table in tables.items():
        table.to_csv(out / f"{name}.csv", index=False)
        files.append(out / f"{name}.csv")
    plot_files = _plots(out, episodes, tables)
    files += [out / name for name in plot_files.values()]
    names = ", ".join(sorted(episodes["dataset"].unique()))
    overall = tables["overall"].iloc[0]
    intro = [
        f"{len(episodes)} episodes from {len(datasets)} dataset(s) ({names}); overall success "
        f"{overall['success_rate']:.3f} [{overall['success_ci_low']:.3f}, {overall['success_ci_high']:.3f}] "
        "(Wilson 95%)." + (f" Learning curves from {len(runs)} run folder(s)." if runs else ""),
        verdict_line(episodes),
        "Recompute with: hingelab report " + " ".join(str(d) for d in datasets)
        + (" --runs " + " ".join(str(r) for r in runs) if runs else "") + f" --out {out}",
    ]
    files += list(write_documents(out, title or f"hingelab report: {names}", intro, _sections(tables, plot_files)))
    provenance = {
        "datasets": [{"path": str(d), "name": name, "episodes": int((episodes["dataset_path"] == str(d)).sum())}
                     for d, name in zip(datasets, [episodes.loc[episodes["dataset_path"] == str(d), "dataset"].iloc[0]
                                                   for d in datasets])],
        "config_hashes": sorted(episodes["config_hash"].dropna().astype(str).unique()),
        "runs": [str(r) for r in runs],
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **code_version(),
    }
    (out / "report.json").write_text(strict_dumps(provenance, out / "report.json", indent=2) + "\n")
    files.append(out / "report.json")
    return Report(out=out, episodes=episodes, tables=tables, files=files)


__all__ = ["FINAL_SUCCESS_SECTION", "build_report", "compute_tables", "verdict_line", "Report"]
