"""``hingelab demo``: the README's main job, a short end-to-end run on shipped defaults.

Each step prints what it measured; a command that a new feature adds gets its step (generate demos,
evaluate the shipped policies, report, Rerun recording) to ``STEPS``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hingelab.json_text import finite_or_null, strict_dumps
from hingelab.out_dir import check_out_file
from hingelab.seeds import seed_argument


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="the main job: run the pipeline as far as it exists on shipped defaults (seconds)",
        description=(
            "Loads the pick scene (Jaka Zu7 + SVH hand + tweezer + 1 cm sphere), holds the "
            "tweezer, opens and closes it with the fingers alone, carries it over a 10 x 10 cm "
            "area of the platform with the Jacobian arm controller, grasps and lifts the sphere "
            "with the privileged hinge command; then records 3 privileged-heuristic episodes of "
            "ToolPick-v0 into datasets/demo_heuristic, runs the shipped low-level policy toward 3 "
            "latent goals on ToolShape-v0 (datasets/demo_low_level), picks the sphere twice with a scripted high level "
            "over that policy (datasets/demo_scripted_hierarchy), imports a rig's ROS 2 bag (datasets/demo_rig_bag) as "
            "real episodes (datasets/demo_real) and exports them back as ROS 2 bags (datasets/demo_real_ros2), "
            "runs a tiny sweep of `train low` (effort reward on and off, 1 seed) on a local one-node Ray "
            "(analysis/demo/sweep, its table sweep.csv), reports on the datasets and the sweep "
            "(analysis/demo/report.html) "
            "and saves a Rerun recording (analysis/demo/demo_heuristic.rrd). Prints what it measured."
        ),
    )
    p.add_argument("--seed", type=seed_argument, default=0, help="seed for the simulation (default 0)")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the measurements as JSON to this file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hingelab.cli.demo_steps import STEPS  # on run: the parser stays light (hingelab.cli)

    if args.out:
        check_out_file(args.out)
    results = {}
    started = time.perf_counter()
    for index, (title, step) in enumerate(STEPS, 1):
        print(f"[{index}/{len(STEPS)}] {title}")
        results[step.__name__] = step(args.seed)
    total = time.perf_counter() - started
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        # a measurement that could not be made (NaN) is null: the file stays JSON
        plain = finite_or_null(json.loads(json.dumps(results, default=float)))
        args.out.write_text(strict_dumps(plain, args.out, indent=2) + "\n")
    where = f" Measurements written to {args.out}." if args.out else ""
    print(f"demo finished in {total:.1f} s: {len(STEPS)} step(s) ran on the shipped scene and defaults.{where}")
    return 0
