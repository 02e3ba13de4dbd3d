"""``hingelab generate heuristic``: privileged heuristic demos on ToolPick-v0, as a dataset."""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.arguments import add_oversubscribe, check_processes, finite_float, positive_int
from hingelab.cli.options import add_max_mesh_mb, add_object_noise, add_ray_argument
from hingelab.folder_lock import folder_lock
from hingelab.out_dir import DATASET, check_out
from hingelab.paths import DATASETS_DIR
from hingelab.rollouts.heuristic_config import HeuristicRunConfig
from hingelab.seeds import seed_argument


def add_heuristic_parser(sources) -> None:

    d = HeuristicRunConfig()
    p = sources.add_parser(
        "heuristic",
        help="privileged heuristic demos on ToolPick-v0 (they pre-fill the high-level replay buffer)",
        description="Run the privileged heuristic (tip positions, direct hinge command: approach, close to "
                    "the object's width, carry to the target 5 cm above) for N episodes of ToolPick-v0 and "
                    "record each as one MCAP episode. The recorded high-level action is the latent reached "
                    "as z_goal and the commanded hand velocity (paper). Same seed, same dataset, whatever "
                    "the number of workers.",
    )
    p.add_argument("--episodes", type=int, default=d.episodes, help=f"number of episodes (default {d.episodes})")
    p.add_argument("--object", default=d.object,
                   help="sphere, cube, cylinder, tetrahedron, or mesh:PATH (an STL, OBJ or PLY file: collided "
                        "through its convex hull, scaled so its largest extent is --size, placed unrotated with "
                        "its z axis up; recorded as mesh:<file name> with the file's sha256), or family:NAME[:SEED] "
                        "(a new object each episode from a procedural family, e.g. family:train or family:holdout; "
                        "each episode records its draw: hingelab.sim.object_families) (default sphere)")
    add_max_mesh_mb(p)
    p.add_argument("--size", type=finite_float, default=d.size,
                   help=f"object width in metres; a mesh's largest extent; a family's size cap, 0.008 to 0.03 "
                        f"(default {d.size})")
    p.add_argument("--mass", type=finite_float, default=d.mass,
                   help=f"object mass in kg; a family's masses come from a density (default {d.mass})")
    p.add_argument("--out", type=Path, required=True,
                   help=f"dataset folder to create (for example {DATASETS_DIR / 'heuristic_sphere'})")
    p.add_argument("--workers", type=positive_int, default=d.workers,
                   help="parallel worker processes (default 1; at most the cores, and no more than --episodes)")
    add_oversubscribe(p)
    p.add_argument("--seed", type=seed_argument, default=d.seed, help=f"base seed (default {d.seed})")
    add_ray_argument(p)
    p.add_argument("--no-randomize", action="store_true", help="turn domain randomization off")
    add_object_noise(p)  # the demos observe the camera's error; the privileged heuristic acts on the truth
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--resume", action="store_true",
                   help="continue a stopped run (a full disk, a kill) in --out to --episodes with the same "
                        "per-episode seeds; the other settings must be the run's")
    p.set_defaults(func=run_heuristic)


def run_heuristic(args: argparse.Namespace) -> int:
    from hingelab.rollouts.heuristic_demos import (  # on run: the parser stays light (hingelab.cli)
        generate_heuristic_dataset,
        summarize,
        timed,
    )

    check_out(args.out, DATASET)
    check_processes(args.workers, "--workers", args.allow_oversubscribe)
    workers = max(1, min(args.workers, args.episodes))  # a worker without an episode would only load the simulator
    config = HeuristicRunConfig(episodes=args.episodes, object=args.object, size=args.size, mass=args.mass,
                                seed=args.seed, workers=workers, randomize=not args.no_randomize,
                                object_noise=args.object_noise, object_noise_model=args.object_noise_model)
    with folder_lock(args.out, args.argv):
        summaries, seconds = timed(generate_heuristic_dataset, args.out, config, progress=not args.no_progress,
                                   resume=args.resume, ray_address=args.ray)
    if not summaries:
        print(f"{args.out} already holds the {config.episodes} episodes; nothing to do.")
        return 0
    resumed = f" (resumed: {config.episodes - len(summaries)} were there)" if args.resume else ""
    print(f"Wrote {args.out}{resumed}: {summarize(summaries, seconds)} "
          f"Inspect it with `hingelab datasets info {args.out}`.")
    return 0
