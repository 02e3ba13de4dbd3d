"""``hingelab report DATASET... [--runs RUNDIR...] --out analysis/NAME``: success rates and learning curves."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "report",
        help="success rates (Wilson 95%%), attempts, lengths, returns, failure reasons and learning curves",
        description=(
            "Count episode datasets with pandas: success rates by source, object shape and size with "
            "Wilson 95% intervals, first-attempt and within-k-attempts rates, episode length and return "
            "distributions, failure reasons; and learning curves (success rate and return against "
            "environment steps, mean and band over seeds) from training run folders (RUNDIR/metrics.csv "
            "with columns env_steps, seed, success_rate, return). Writes report.md, report.html, PNG "
            "plots and CSV tables into --out."
        ),
    )
    p.add_argument("datasets", type=Path, nargs="+", metavar="DATASET", help="dataset folders to count")
    p.add_argument("--runs", type=Path, nargs="+", action="extend", default=[], metavar="RUNDIR",
                   help="training run folders (each with metrics.csv, or */metrics.csv per seed)")
    p.add_argument("--out", type=Path, required=True, help="report folder, e.g. analysis/NAME")
    p.add_argument("--allow-dirty", action="store_true",
                   help="write under analysis/ even if platform/, assets/ or pyproject.toml have uncommitted "
                        "changes (the report then names the commit +dirty and a hash of the changes)")
    p.add_argument("--title", default=None, help="report title (default: the dataset names)")
    p.add_argument("--attempts", type=int, nargs="+", default=[1, 2, 3], metavar="K",
                   help="k of the within-k-attempts rates (default 1 2 3)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hingelab.analysis import build_report
    from hingelab.errors import ConfigError
    from hingelab.provenance import require_clean_for

    require_clean_for(args.out, args.allow_dirty, "hingelab report")
    if any(k < 1 for k in args.attempts):
        raise ConfigError(f"--attempts must be positive integers, not {args.attempts}")
    started = time.perf_counter()
    print(f"report: counting {len(args.datasets)} dataset(s)"
          + (f" and {len(args.runs)} run folder(s)" if args.runs else "") + " ...")
    report = build_report(args.datasets, args.out, runs=args.runs, title=args.title, attempts_k=args.attempts)
    overall = report.tables["overall"].iloc[0]
    by_source = report.tables["success_by_source"]
    sources = ", ".join(f"{r.source} {r.success_rate:.3f} ({r.successes}/{r.episodes})"
                        for r in by_source.itertuples())
    print(f"Counted {len(report.episodes)} episodes in {time.perf_counter() - started:.1f} s: overall success "
          f"{overall['success_rate']:.3f} [{overall['success_ci_low']:.3f}, {overall['success_ci_high']:.3f}] "
          f"(Wilson 95%); by source: {sources}. Wrote {len(report.files)} files to {report.out}: "
          f"{report.markdown.name}, {report.html.name}, the CSV tables and PNG plots.")
    return 0
