"""``hingelab sweep SWEEP.toml --out DIR [--address ADDR] [--resume]``: a grid of training runs on Ray."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from hingelab.arguments import positive_int
from hingelab.errors import ConfigError
from hingelab.folder_lock import folder_lock
from hingelab.out_dir import SWEEP, check_out


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="a grid of training runs (seeds x conditions) as Ray tasks, on this machine or a Ray cluster",
        description=(
            "Run every trial of a sweep file (one training command, seeds x conditions) as a Ray task, each a "
            "normal run folder DIR/<condition>_seed<S> (hingelab report --runs DIR groups them by condition). "
            "DIR/sweep.csv lists every trial with its state, wall time and final metrics and is refreshed as "
            "trials start and end; a table shows progress. The file:\n\n"
            "  [sweep]\n  command = \"train low\"          # train low | train high | train flat\n"
            "  seeds = [0, 1, 2]\n  args = [\"--steps\", \"30000\"]    # given to every trial\n"
            "  cpus_per_trial = 1             # --envs and --threads of each trial (unless args set them)\n\n"
            "  [conditions]                   # name = extra arguments\n  effort = []\n"
            "  no_effort = [\"--no-effort\"]\n\n"
            "Without --address a local one-node Ray gets this machine's cores (--cpus); with it the sweep joins "
            "a running cluster (`ray start --head` on one node, `ray start --address ADDR` on the others), whose "
            "nodes must all see DIR at the same path (shared storage such as NFS) and have hingelab installed."),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("sweep_file", type=Path, metavar="SWEEP.toml", help="the sweep file")
    p.add_argument("--out", type=Path, required=True,
                   help="the sweep folder (new, or the stopped sweep's with --resume)")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="join the Ray cluster at ADDR (host:port from `ray start --head`, or auto) instead of "
                        "starting a local one")
    p.add_argument("--cpus", type=positive_int, default=None,
                   help="CPUs of the local Ray, at least 1 (default: every core of this machine); not with --address")
    p.add_argument("--resume", action="store_true",
                   help="continue a stopped sweep in --out: finished trials are kept, the others continue from "
                        "their last checkpoint (a trial without one starts again)")
    p.add_argument("--no-progress", action="store_true", help="no live table (the summary still ends the run)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hingelab.sweeps.runner import run_sweep, summary  # on run: the parser stays light (hingelab.cli)
    from hingelab.sweeps.spec import load_sweep

    check_out(args.out, SWEEP)
    if args.address is not None and args.cpus is not None:
        raise ConfigError("--cpus sizes a local Ray; a cluster joined with --address has its own CPUs")
    spec = load_sweep(args.sweep_file)  # every trial's command line checked before anything starts
    started = time.perf_counter()
    try:
        with folder_lock(args.out, args.argv):  # the driver's; each trial's train locks its own run folder
            records = run_sweep(spec, args.out, address=args.address, resume=args.resume, num_cpus=args.cpus,
                                progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"Sweep stopped; continue it with: hingelab sweep {args.out / 'sweep.toml'} --out {args.out} --resume",
              flush=True)
        raise
    print(summary(spec, args.out, records, time.perf_counter() - started, args.address))
    return 0
