"""``hingelab report DATASET... [--runs RUNDIR...] --out analysis/NAME``: success rates and learning curves;
``hingelab report --pool DIR... [--pool DIR...] --out DIR``: pooled success over evaluation folders."""

from __future__ import annotations

import argparse
import shlex
import time
from pathlib import Path

from hingelab.arguments import finite_float
from hingelab.cli.options import add_on_corrupt
from hingelab.errors import ConfigError
from hingelab.out_dir import REPORT, check_out
from hingelab.provenance import require_clean_for


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "report",
        help="success rates (Wilson 95%%), attempts, lengths, returns, failure reasons and learning curves; "
             "pooled success over evaluation folders (--pool)",
        description=(
            "Count episode datasets with pandas: success rates by source, object shape and size with "
            "Wilson 95% intervals, first-attempt and within-k-attempts rates, episode length and return "
            "distributions, failure reasons; and learning curves (success rate and return against "
            "environment steps, mean and band over seeds) from training run folders (RUNDIR/metrics.csv "
            "with columns env_steps, seed, success_rate, return). Writes report.md, report.html, PNG "
            "plots and CSV tables into --out. "
            "With --pool DIR... instead of DATASETs: pooled success over `hingelab eval low` folders (their "
            "episodes.csv; old files count settled_success, new ones success, the settled verdict either way), "
            "per folder and pooled, with Wilson 95% intervals, with and without the tool < 1 cm, per goal third "
            "and per band of the goal's opening (--bands); writes pooled.md, pooled.csv and by_region.csv."
        ),
    )
    p.add_argument("datasets", type=Path, nargs="*", metavar="DATASET",
                   help="dataset folders to count (not with --pool)")
    p.add_argument("--runs", type=Path, nargs="+", action="extend", default=[], metavar="RUNDIR",
                   help="training run folders (each with metrics.csv, or */metrics.csv per seed)")
    p.add_argument("--pool", type=Path, nargs="+", action="append", default=[], metavar="DIR",
                   help="evaluation folders to pool (written by `hingelab eval low`: episodes.csv), or their "
                        "episodes.csv files, or evaluation datasets; repeat --pool for several pools in one report")
    p.add_argument("--pool-name", action="append", default=[], metavar="NAME",
                   help="name of each --pool in order (default: from the folder names, e.g. experts_goals_seed3-5)")
    p.add_argument("--bands", type=finite_float, nargs="+", default=None, metavar="RAD",
                   help="edges of the goal-opening bands of --pool (default 0.10 0.18 0.22: < 0.10, 0.10-0.18, "
                        "0.18-0.22, >= 0.22 rad)")
    p.add_argument("--picks", type=Path, nargs="+", default=[], metavar="DIR",
                   help="the pick table instead: `hingelab eval high --out` folders (a policy on one shape and "
                        "size each), first-attempt and overall success with Wilson 95%% intervals, pooled per "
                        "policy; writes picks.md and picks.csv")
    p.add_argument("--out", type=Path, required=True, help="report folder, e.g. analysis/NAME")
    p.add_argument("--allow-dirty", action="store_true",
                   help="write under analysis/ even if platform/, assets/ or pyproject.toml have uncommitted "
                        "changes (the report then names the commit +dirty and a hash of the changes)")
    p.add_argument("--title", default=None, help="report title (default: the dataset names, or the pools' names)")
    p.add_argument("--attempts", type=int, nargs="+", default=[1, 2, 3], metavar="K",
                   help="k of the within-k-attempts rates (default 1 2 3)")
    add_on_corrupt(p)
    p.set_defaults(func=run)


def pool_command(args: argparse.Namespace) -> str:
    """The command line that makes this pooled report, as pooled.md records it."""
    words = ["hingelab", "report"]
    for paths in args.pool:
        words += ["--pool", *map(str, paths)]
    for name in args.pool_name:
        words += ["--pool-name", name]
    if args.bands is not None:
        words += ["--bands", *(f"{b:g}" for b in args.bands)]
    if args.title:
        words += ["--title", args.title]
    words += ["--out", str(args.out)]
    return shlex.join(words)


def run_pool(args: argparse.Namespace) -> int:
    import pandas as pd  # on run: the parser stays light (hingelab.cli)

    from hingelab.analysis.pooled import DEFAULT_BAND_EDGES, write_pooled

    if args.datasets or args.runs:
        raise ConfigError("give DATASET... (with --runs) or --pool DIR..., not both")
    if args.pool_name and len(args.pool_name) != len(args.pool):
        raise ConfigError(f"{len(args.pool_name)} --pool-name for {len(args.pool)} --pool; name every pool or none")
    require_clean_for(args.out, args.allow_dirty, "hingelab report --pool")
    started = time.perf_counter()
    names = args.pool_name or [None] * len(args.pool)
    report = write_pooled(list(zip(names, args.pool)), args.out,
                          edges=tuple(args.bands) if args.bands is not None else DEFAULT_BAND_EDGES,
                          title=args.title, command=pool_command(args))
    rows = report.pooled
    lines = []
    for name, group in rows.groupby("pool", sort=False):
        r = group.iloc[-1]  # the pooled row (or the one folder's)
        drift = ("" if pd.isna(r["successes_drift_under_1cm"])
                 else f", with the tool < 1 cm {int(r['successes_drift_under_1cm'])}/{r['episodes']} = "
                      f"{r['success_drift_under_1cm_rate']:.3f} [{r['drift_ci_low']:.3f}, {r['drift_ci_high']:.3f}]")
        lines.append(f"{name} ({len(group) - (len(group) > 1)} folder(s)): {r['successes']}/{r['episodes']} = "
                     f"{r['success_rate']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}]{drift}")
    print(f"Pooled {len(args.pool)} pool(s) in {time.perf_counter() - started:.1f} s (Wilson 95%; the settled "
          f"verdict: settled_success in old episodes.csv files, success in new ones): " + "; ".join(lines)
          + f". Wrote {', '.join(f.name for f in report.files)} to {report.out}.")
    return 0


def run_picks(args: argparse.Namespace) -> int:
    from hingelab.analysis.pick_table import write_picks  # on run: the parser stays light (hingelab.cli)

    if args.datasets or args.pool or args.runs:
        raise ConfigError("give --picks DIR... alone (not with DATASETs, --runs or --pool)")
    require_clean_for(args.out, args.allow_dirty, "hingelab report --picks")
    command = "hingelab report --picks " + " ".join(map(str, args.picks)) + f" --out {args.out}"
    table = write_picks(args.picks, args.out, command)
    for row in table[table["object"] == "all"].itertuples():
        print(f"{row.policy} over {row.low_level}: {row.episodes} episodes, first attempt "
              f"{row.first_attempt_success_rate:.3f} "
              f"[{row.first_attempt_ci_low:.3f}, {row.first_attempt_ci_high:.3f}], "
              f"overall {row.success_rate:.3f} [{row.ci_low:.3f}, {row.ci_high:.3f}], lowest set "
              f"{row.lowest_set_success_rate:.2f}")
    print(f"Wrote {args.out}/picks.md and picks.csv.")
    return 0


def run_runs(args: argparse.Namespace) -> int:
    """Training runs alone: curves grouped by run label (a sweep's condition), success at the end across seeds."""
    from hingelab.analysis.run_report import build_run_report  # on run: the parser stays light (hingelab.cli)

    require_clean_for(args.out, args.allow_dirty, "hingelab report --runs")
    command = "hingelab report --runs " + " ".join(map(str, args.runs)) + f" --out {args.out}"
    report = build_run_report(args.runs, args.out, title=args.title, command=command)
    final = report.tables["final_success"]
    lines = [f"{r.run}: {r.success_rate_mean:.2f}" + (f" [{r.success_rate_ci_low:.2f}, {r.success_rate_ci_high:.2f}]"
                                                    if r.seeds > 1 else "") + f" over {r.seeds} seed(s)"
             for r in final.itertuples()]
    print(f"Success at the last evaluation (Student-t 95% across seeds): {'; '.join(lines)}. Wrote "
          f"{len(report.files)} files to {report.out}: report.md, report.html, final_success.csv, the curves.")
    return 0


def run(args: argparse.Namespace) -> int:
    from hingelab.analysis import build_report  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    if args.picks:
        return run_picks(args)
    if args.pool:
        return run_pool(args)
    if args.pool_name or args.bands is not None:
        raise ConfigError("--pool-name and --bands go with --pool DIR...")
    if not args.datasets and args.runs:
        return run_runs(args)
    if not args.datasets:
        raise ConfigError("give at least one DATASET folder to count, --runs RUNDIR... (training runs or a sweep "
                          "folder) or --pool DIR... to pool evaluation folders")
    require_clean_for(args.out, args.allow_dirty, "hingelab report")
    if any(k < 1 for k in args.attempts):
        raise ConfigError(f"--attempts must be positive integers, not {args.attempts}")
    started = time.perf_counter()
    print(f"report: counting {len(args.datasets)} dataset(s)"
          + (f" and {len(args.runs)} run folder(s)" if args.runs else "") + " ...")
    report = build_report(args.datasets, args.out, runs=args.runs, title=args.title, attempts_k=args.attempts)
    overall = report.tables["overall"].iloc[0]
    by_source = report.tables["success_by_source"]
    sources = ", ".join(f"{r.source} {r.success_rate:.3f} ({r.successes}/{r.episodes}"
                        + (f"; success = {r.verdict}" if isinstance(getattr(r, "verdict", None), str) else "") + ")"
                        for r in by_source.itertuples())
    print(f"Counted {len(report.episodes)} episodes in {time.perf_counter() - started:.1f} s: overall success "
          f"{overall['success_rate']:.3f} [{overall['success_ci_low']:.3f}, {overall['success_ci_high']:.3f}] "
          f"(Wilson 95%); by source: {sources}. Wrote {len(report.files)} files to {report.out}: "
          f"{report.markdown.name}, {report.html.name}, the CSV tables and PNG plots.")
    return 0
