"""``hingelab generate SOURCE``: run a source and write its episodes into a dataset folder.

One sub-subcommand per source. ``SOURCES`` maps a source name to the function that adds
its sub-subcommand (``"module:function"``, imported on use), so a later source
(``heuristic``, ``low``, ``high``, ...) is one entry here and one module of its own.
Each sub-subcommand's ``func`` writes the dataset, shows progress and ends with a
one-paragraph summary.
"""

from __future__ import annotations

import argparse
import importlib
import time
from pathlib import Path

from hingelab.arguments import finite_float
from hingelab.folder_lock import folder_lock
from hingelab.out_dir import DATASET, check_out
from hingelab.paths import DATASETS_DIR
from hingelab.perception.cloud_dataset_config import CloudDatasetConfig
from hingelab.seeds import seed_argument

# source name -> "module:function" adding its sub-subcommand to the ``generate`` subparsers
SOURCES = {
    "clouds": "hingelab.cli.generate:add_clouds_parser",
    "heuristic": "hingelab.cli.generate_heuristic:add_heuristic_parser",
}


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "generate",
        help="run a source for N episodes and write each as one MCAP file into a dataset folder",
        description="Run a source and write a dataset (a folder with dataset.json and episodes/*.mcap; "
                    f"see datasets/README.md). Sources: {', '.join(SOURCES)}.",
    )
    sources = p.add_subparsers(title="sources", metavar="SOURCE", required=True)
    for name, target in SOURCES.items():
        module, function = target.split(":")
        getattr(importlib.import_module(module), function)(sources)


# ---------------------------------------------------------------------------- clouds
def add_clouds_parser(sources) -> None:

    d = CloudDatasetConfig()
    p = sources.add_parser(
        "clouds",
        help="synthetic tweezer point clouds over the hinge range (the encoder's training data)",
        description="Tweezer clouds at uniform openings in random poses around the in-hand pose, with the "
                    "paper's encoder augmentation (20% removal, 5 mm noise), ground-truth opening, tip gap "
                    "and pose on /sim/privileged; clouds are grouped per episode file.",
    )
    p.add_argument("--n", type=int, default=d.n_clouds, help=f"number of clouds (default {d.n_clouds})")
    p.add_argument("--out", type=Path, required=True,
                   help=f"dataset folder to create (for example {DATASETS_DIR / 'clouds'})")
    p.add_argument("--seed", type=seed_argument, default=d.seed,
                   help=f"base seed; episode k uses seed + k (default {d.seed})")
    p.add_argument("--per-episode", type=int, default=d.clouds_per_episode,
                   help=f"clouds per episode file (default {d.clouds_per_episode})")
    p.add_argument("--noise", type=finite_float, default=d.noise_std_m,
                   help=f"per-point Gaussian noise, metres (default {d.noise_std_m}); with --noise-max, the "
                        "lowest noise level")
    p.add_argument("--noise-max", type=finite_float, default=d.noise_std_max_m,
                   help="draw each cloud's noise level uniformly from [--noise, --noise-max] metres, so the "
                        "encoder learns to read the opening at any noise level (the sim's clouds have 3 mm, "
                        f"the paper's encoder augmentation 5 mm; default {d.noise_std_max_m})")
    p.add_argument("--removal", type=finite_float, default=d.removal_fraction,
                   help=f"fraction of points removed (default {d.removal_fraction})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_clouds)


def run_clouds(args: argparse.Namespace) -> int:
    from hingelab.perception.synthetic_dataset import (
        generate_cloud_dataset,  # on run: the parser stays light (hingelab.cli)
    )

    check_out(args.out, DATASET)
    config = CloudDatasetConfig(n_clouds=args.n, clouds_per_episode=args.per_episode, seed=args.seed,
                                noise_std_m=args.noise, noise_std_max_m=args.noise_max,
                                removal_fraction=args.removal)
    start = time.perf_counter()
    with folder_lock(args.out, args.argv):
        dataset = generate_cloud_dataset(args.out, config, progress=not args.no_progress)
    seconds = time.perf_counter() - start
    index = dataset.index
    size_mb = sum(p.stat().st_size for p in dataset.paths()) / 1e6
    print(f"Wrote {int(index['length'].sum())} tweezer clouds in {len(index)} episode files "
          f"({size_mb:.1f} MB) to {dataset.root} in {seconds:.1f} s ({index['length'].sum() / seconds:.0f} "
          f"clouds/s), seed {config.seed}. Openings are uniform over the hinge range, poses within "
          f"{config.max_angle_deg:g} degrees and {config.max_offset_m * 100:g} cm of the in-hand pose, with "
          f"{'-'.join(f'{x * 1000:g}' for x in sorted(set(config.noise_range_m)))} mm noise and "
          f"{config.removal_fraction:.0%} removal; the ground truth "
          f"is on /sim/privileged. Next: hingelab train encoder --data {dataset.root}")
    return 0
