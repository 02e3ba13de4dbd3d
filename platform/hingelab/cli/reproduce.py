"""``hingelab reproduce --out DIR [--resume]``: the shipped set from scratch, each stage a normal command
(``hingelab.sweeps.reproduce`` does the work; this module parses and prints)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.out_dir import REPRODUCTION, check_out
from hingelab.sweeps.reproduce_plan import SCALES, describe_plan, plan_stages


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "reproduce",
        help="make the shipped checkpoints again from scratch and compare them with the shipped ones",
        description=(
            "Make the whole shipped set again from scratch with the recipes of assets/checkpoints/README.md and "
            "analysis/high-level/README.md, each stage the hingelab command a user would type, in its own folder "
            "DIR/stages/NAME (a run folder, a dataset or a checkpoint) with its output in DIR/logs/NAME.log:\n\n"
            "  clouds, encoder          generate clouds; train encoder (encoder.pt)\n"
            "  low_demos                eval low --baseline synergy (the low level's demonstrations)\n"
            "  low_open, low_closed     train low: the two goal-region experts (low_level.zip, "
            "low_level_closed.zip)\n"
            "  low_experts              compose low (low_level_experts.json)\n"
            "  high                     train high --learner dagger: its phase clone (base.zip), then DAgger "
            "(high_level.zip)\n"
            "  eval_low_*, picks_*      eval low and eval high of the reproduced and the shipped policies on the "
            "same seeds\n\n"
            "The stages after the encoder run with HINGELAB_ASSETS=DIR/assets: links to the checkout's assets whose "
            "checkpoints/encoder.pt is the reproduced encoder, so they perceive through it. DIR/reproduce.json holds "
            "each stage's command line, status, times and outputs; DIR/reproduce.md and .csv compare each product "
            "with the shipped asset (encoder opening R^2, low-level settled success, pick success) with the wall "
            "time of its stages. After a kill, --resume keeps the done stages, continues the unfinished one with its "
            "command's own --resume where it has one (else starts it again) and runs the rest. --plan prints the "
            "stages and their commands without running anything."),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", type=Path, required=True,
                   help="the reproduction folder (new or empty; with --resume, the stopped reproduction's)")
    p.add_argument("--resume", action="store_true",
                   help="continue the reproduction in --out: done stages are kept (their outputs checked), the "
                        "unfinished one goes on from where it stopped, the later ones run")
    p.add_argument("--scale", choices=SCALES, default=None,
                   help="shipped: the shipped recipes (hours on 2 cores); tiny: every stage with tiny sizes (few "
                        "steps, episodes, clouds; minutes), for tests and smoke runs (default shipped; a resumed "
                        "reproduction keeps its own)")
    p.add_argument("--jobs", type=int, default=2,
                   help="stages run at once, as local processes, when they do not wait on each other (each "
                        "stage's training uses one core; default 2)")
    p.add_argument("--plan", action="store_true", help="print the stages and their commands; run nothing")
    p.add_argument("--no-progress", action="store_true", help="no line per stage start and end")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_out(args.out, REPRODUCTION)
    if args.plan:
        print(describe_plan(plan_stages(args.out, args.scale or "shipped"), args.out.resolve()))
        return 0
    from hingelab.sweeps.reproduce import run_reproduction  # on run: the parser stays light (hingelab.cli)

    try:
        result = run_reproduction(args.out, scale=args.scale, resume=args.resume, jobs=args.jobs,
                                  progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"Reproduction stopped; continue it with: hingelab reproduce --out {args.out} --resume", flush=True)
        raise
    print((args.out / "reproduce.md").read_text())
    print(result.summary)
    return 0
