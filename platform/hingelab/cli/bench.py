"""``hingelab bench NAME``: run one benchmark, print its table, write it under analysis/bench/ (or the
benchmark's own folder, ``hingelab.bench.table_dir``: analysis/reliability/ for ``reliability``).

``hingelab bench --stale``: say which committed tables are stale, since which commit, and the command
that regenerates each (a report: it exits 0 whether or not any is stale).
"""

from __future__ import annotations

import argparse
import importlib
import textwrap
from pathlib import Path

from hingelab.bench import BENCHMARKS, table_dir
from hingelab.bench.freshness import HistoryUnavailable, report
from hingelab.errors import ConfigError, HingelabError
from hingelab.out_dir import REPORT, check_out
from hingelab.paths import ANALYSIS_DIR, REPO_ROOT
from hingelab.provenance import code_version, require_clean_for


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="run a benchmark (ours vs a named baseline, one run; reliability: adversarial probes) and write "
             "analysis/bench/NAME.md; "
             "--stale: which committed tables are stale",
        usage="%(prog)s NAME [--quick] [--encoder ENCODER] [--out OUT] [--allow-dirty]\n"
              "       %(prog)s --stale [NAME]",
        description="\n\n".join(textwrap.fill(paragraph, width=92) for paragraph in (
            "Run one benchmark, print its table, and write analysis/bench/NAME.md and "
            "NAME.json with the figures, the baseline's figures, their ratio, the machine "
            "and the code version. Benchmarks: " + ", ".join(BENCHMARKS) + ".",
            "reliability has no baseline: it runs adversarial probes (concurrent writers on one folder, "
            "a kill and --resume, crafted episode ids, out-of-range seeds, unusable --out, a huge mesh, "
            "dangling symlinks, a bag imported twice) as hingelab processes in temporary folders, and writes "
            "analysis/reliability/reliability.md and .json: per probe its commands, exit codes, tracebacks, "
            "writes outside --out and episodes expected, found, duplicated and lost, with their totals.",
            "--stale runs nothing: it prints one line per committed table (under analysis/bench/; "
            "analysis/reliability/ for reliability) (or for NAME only), saying whether it is current or "
            "stale. A table is stale once a commit "
            "after the one it records changed the code it measures (the benchmark's MEASURES, its own "
            "module, the locked versions in constraints.txt), or if it was made from uncommitted code; "
            "its line names the commits since and the command that regenerates it (hingelab bench NAME). "
            "It exits 0 whether or not a table is stale, and 1 with a one-line reason if the git history "
            "cannot be read (not a git checkout, a shallow clone).",
        )),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("name", nargs="?", default=None,
                   help="which benchmark: " + ", ".join(BENCHMARKS) + " (with --stale: report this table only)")
    p.add_argument("--stale", action="store_true",
                   help="run nothing: report which committed tables are stale, since which commit, and the "
                        "command that regenerates each (exit 0 either way; 1 if the git history cannot be read)")
    p.add_argument("--quick", action="store_true", help="a short run (for tests; noisier figures)")
    p.add_argument("--encoder", type=Path, default=None,
                   help="perception only: an encoder checkpoint to measure instead of the shipped one")
    p.add_argument("--out", type=Path, default=None,
                   help="folder for NAME.md and NAME.json (default: analysis/bench/; reliability: "
                        "analysis/reliability/)")
    p.add_argument("--allow-dirty", action="store_true",
                   help="write under analysis/ even if platform/, assets/ or pyproject.toml have uncommitted "
                        "changes (the table then names the commit +dirty and a hash of the changes)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.stale:
        return report_stale(args)
    if args.name is None:
        raise ConfigError(f"name a benchmark ({', '.join(BENCHMARKS)}), or --stale to see which tables are stale")
    if args.name not in BENCHMARKS:
        raise ConfigError(f"unknown benchmark {args.name!r}; choose one of: {', '.join(BENCHMARKS)}")
    try:
        module = importlib.import_module(BENCHMARKS[args.name])
    except ModuleNotFoundError as exc:
        if exc.name == BENCHMARKS[args.name]:
            raise ConfigError(f"benchmark {args.name!r} is not built yet in this version") from exc
        raise
    options = {}
    if args.encoder is not None:
        if args.name != "perception":
            raise ConfigError("--encoder is an option of `hingelab bench perception` only")
        options["encoder"] = args.encoder
    # before the run, not after: a long benchmark must not end in a refusal
    check_out(args.out or table_dir(args.name), REPORT)
    require_clean_for(args.out or table_dir(args.name), args.allow_dirty, f"hingelab bench {args.name}")
    code_version()  # the version as the run starts (cached)
    table = module.run(quick=args.quick, **options)
    print(table.markdown())
    md_path, json_path = table.write(args.out)
    print(f"wrote {md_path} and {json_path}")
    verdict = getattr(module, "verdict", None)  # a benchmark that can fail (reliability) says so, table written
    problem = verdict(table) if verdict is not None else None
    if problem:
        raise HingelabError(f"{problem}: {md_path}")
    return 0


def report_stale(args: argparse.Namespace) -> int:
    """Print one line per committed table (current or why stale) and a summary; 0 whether stale or not."""
    used = [flag for flag, value in (("--quick", args.quick), ("--encoder", args.encoder), ("--out", args.out),
                                     ("--allow-dirty", args.allow_dirty)) if value not in (False, None)]
    if used:
        raise ConfigError(f"--stale runs no benchmark: {' and '.join(used)} "
                          f"{'does' if len(used) == 1 else 'do'} not apply")
    if args.name is not None and args.name not in BENCHMARKS:
        raise ConfigError(f"unknown benchmark {args.name!r}; choose one of: {', '.join(BENCHMARKS)}")
    names = [args.name] if args.name is not None else list(BENCHMARKS)
    try:
        lines = report(REPO_ROOT, ANALYSIS_DIR / "bench", names, table_dir=table_dir)
    except HistoryUnavailable as exc:
        raise ConfigError(f"cannot tell which benchmark tables are stale: {exc}") from None
    for line, _ in lines:
        print(line)
    stale = sum(is_stale for _, is_stale in lines)
    if stale:
        print(f"{stale} of {len(lines)} table{'s' * (len(lines) > 1)} stale: regenerate each with the command on "
              "its line, from a clean checkout on an idle machine (analysis/bench/README.md)")
    else:
        print(f"all {len(lines)} table{'s' * (len(lines) > 1)} current")
    return 0
