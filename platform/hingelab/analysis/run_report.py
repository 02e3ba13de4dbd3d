"""``build_run_report(runs, out)``: the report of training runs alone (``hingelab report --runs DIR...``
without datasets), e.g. a sweep's trials grouped by condition.

Writes into ``out``: learning_curves.csv (mean and std over seeds per run label), learning_curves_by_seed.csv,
seeds.csv, final_success.csv (success at the end with a Student-t 95% interval across seeds), their
plots, report.md, report.html and report.json (runs, code version).
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import pandas as pd

from hingelab.analysis import plots
from hingelab.analysis.documents import Section, write_documents
from hingelab.analysis.learning_curves import (
    METRICS_FILE,
    REACH_LEVEL,
    expand_sweeps,
    final_success,
    load_learning_curves,
    load_seed_curves,
    seed_summary,
)
from hingelab.analysis.report import FINAL_SUCCESS_SECTION, Report
from hingelab.json_text import strict_dumps
from hingelab.provenance import code_version


def build_run_report(runs, out, title: str | None = None, command: str | None = None) -> Report:
    given = [Path(r) for r in runs]
    runs = expand_sweeps(given)
    curves = load_learning_curves(runs)
    seed_curves = load_seed_curves(runs)
    seeds = seed_summary(seed_curves)
    tables = {"learning_curves": curves, "learning_curves_by_seed": seed_curves, "seeds": seeds,
              "final_success": final_success(seeds)}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for name, table in tables.items():
        table.to_csv(out / f"{name}.csv", index=False)
        files.append(out / f"{name}.csv")
    curve_png = plots.learning_curve_plot(curves, out / "learning_curves.png")
    seed_png = plots.seed_curve_plot(seed_curves, out / "learning_curves_by_seed.png")
    files += [curve_png, seed_png]
    labels = ", ".join(f"{r.run} ({r.seeds} seed{'s' if r.seeds != 1 else ''})"
                       for r in tables["final_success"].itertuples())
    intro = [f"Learning curves of {len(runs)} run folder(s), grouped by run label (run.json; a sweep's "
             f"condition): {labels}.",
             "Recompute with: " + (command or "hingelab report --runs " + " ".join(map(str, given)) + f" --out {out}")]
    sections = [
        Section("Learning curves", f"From the run folders' {METRICS_FILE}: mean over seeds, band +- one std.",
                None, "learning_curves.csv", [curve_png.name]),
        Section("Success of every seed", "Each seed's evaluations (thin) and their mean (thick), per run label. "
                f"The table: per label and seed, the first evaluation whose success rate reached {REACH_LEVEL:g} "
                "(empty: none did) and the last evaluation.", seeds, "seeds.csv", [seed_png.name]),
        Section(*FINAL_SUCCESS_SECTION, tables["final_success"], "final_success.csv"),
    ]
    files += list(write_documents(out, title or "hingelab report: training runs", intro, sections))
    provenance = {"runs": [str(r) for r in runs], "given": [str(r) for r in given],
                  "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), **code_version()}
    (out / "report.json").write_text(strict_dumps(provenance, out / "report.json", indent=2) + "\n")
    files.append(out / "report.json")
    return Report(out=out, episodes=pd.DataFrame(), tables=tables, files=files)


__all__ = ["build_run_report"]
