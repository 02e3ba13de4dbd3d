"""``hingelab bench NAME``: run one benchmark, print its table, write it under analysis/bench/."""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

from hingelab.bench import BENCHMARKS
from hingelab.errors import ConfigError
from hingelab.paths import ANALYSIS_DIR
from hingelab.provenance import code_version, require_clean_for


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="run a benchmark (ours vs a named baseline, one run) and write analysis/bench/NAME.md",
        description=(
            "Run one benchmark, print its table, and write analysis/bench/NAME.md and "
            "NAME.json with the figures, the baseline's figures, their ratio, the machine "
            "and the code version. Benchmarks: " + ", ".join(BENCHMARKS) + "."
        ),
    )
    p.add_argument("name", help="which benchmark: " + ", ".join(BENCHMARKS))
    p.add_argument("--quick", action="store_true", help="a short run (for tests; noisier figures)")
    p.add_argument("--encoder", type=Path, default=None,
                   help="perception only: an encoder checkpoint to measure instead of the shipped one")
    p.add_argument("--out", type=Path, default=None,
                   help="folder for NAME.md and NAME.json (default: analysis/bench/)")
    p.add_argument("--allow-dirty", action="store_true",
                   help="write under analysis/ even if platform/, assets/ or pyproject.toml have uncommitted "
                        "changes (the table then names the commit +dirty and a hash of the changes)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
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
    require_clean_for(args.out or ANALYSIS_DIR / "bench", args.allow_dirty, f"hingelab bench {args.name}")
    code_version()  # the version as the run starts (cached)
    table = module.run(quick=args.quick, **options)
    print(table.markdown())
    md_path, json_path = table.write(args.out)
    print(f"wrote {md_path} and {json_path}")
    return 0
