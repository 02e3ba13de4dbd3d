"""``hingelab eval WHAT CHECKPOINT``: run a trained policy and write an evaluation dataset
(``hingelab.rollouts.evaluation`` does the work; this module parses and prints).

``low``: the low-level policy on ToolShape-v0 toward reachable goals stratified over the
opening range; every episode is an MCAP episode in ``--out``; the report is the success
rate per goal region (thirds of the reachable opening range) with Wilson 95% intervals.
Success is the env's one verdict (ToolShape-v0: settled over the last 0.5 s), the episodes'
recorded ``success``, so ``hingelab report`` of ``--out`` counts the same episodes.

``high``: a high-level checkpoint (SAC or phase clone), or a baseline (heuristic, scripted, scripted-observed,
scripted-perceived, scripted-feedback, random), on ToolPick-v0
(``hingelab.rollouts.high_level``): success within 200 steps and at the first attempt,
attempts and failure reasons per episode; a table with Wilson 95% intervals (table.csv, report.md).

``picks``: a high-level checkpoint (or a baseline) on each of the pick table's sets, one ``eval high`` dataset per
set and the pooled pick table (``hingelab.rollouts.pick_sets``).

``perception``: the depth camera's perception against the synthesized clouds on the same poses
(``hingelab.cli.eval_perception``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.arguments import finite_float
from hingelab.cli import eval_perception
from hingelab.cli.names import BASELINES, TOOL_POSITIONS
from hingelab.cli.options import add_max_mesh_mb, add_object_noise, add_object_perception, add_ray_argument
from hingelab.errors import ConfigError
from hingelab.folder_lock import command_line, folder_lock
from hingelab.out_dir import DATASET, check_out
from hingelab.seeds import seed_argument


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("eval", help="evaluate a trained policy into a dataset",
                              description="Evaluate a trained policy; every episode is written to a dataset.")
    what = p.add_subparsers(title="policies", metavar="WHAT", required=True)
    low = what.add_parser(
        "low", help="the low-level policy (hingelab train low) on ToolShape-v0",
        description="Run a low-level checkpoint toward N reachable latent goals (openings stratified over the "
                    "reachable range, deterministic actions, domain randomization as in training) and write "
                    "each episode into the dataset --out, with a per-region success table (report.md, "
                    "regions.csv) and one row per episode (episodes.csv).")
    low.add_argument("checkpoint", type=Path, nargs="?", default=None,
                     help="a model.zip or best_model.zip from hingelab train low, a run folder or one of "
                          "its checkpoints/step_* folders (their model.zip), or a goal-region experts manifest "
                          "from hingelab compose low (default: the shipped low-level policy)")
    low.add_argument("--episodes", type=int, default=60, help="evaluation episodes (default 60)")
    low.add_argument("--out", type=Path, required=True, help="dataset folder to write (must be new or empty)")
    low.add_argument("--seed", type=seed_argument, default=0, help="seed of the goals and episodes (default 0)")
    low.add_argument("--baseline", default=None, metavar="{" + ",".join(BASELINES["low"]) + "}",
                     help="evaluate a reference instead of a checkpoint: hold-still (zero finger changes) or "
                          "synergy (the scripted controller: z_goal -> calibrated opening -> grasp-synergy "
                          "finger targets)")
    low.add_argument("--no-randomize", action="store_true", help="evaluate without domain randomization")
    low.add_argument("--perception", choices=("synthesized", "camera"), default="synthesized",
                     help="where the tool clouds come from: synthesized from the tool's model (default, as in "
                          "training) or the rendered depth camera through the camera cloud pipeline")
    low.add_argument("--no-progress", action="store_true", help="no progress bar")
    low.add_argument("--resume", action="store_true",
                      help="continue a stopped evaluation (a full disk, a kill) in --out: its finished episodes are "
                           "kept, the rest run with their own seeds; the other settings must be the same")
    add_ray_argument(low)
    low.set_defaults(func=run_low)
    high = what.add_parser(
        "high", help="a high-level policy (or a baseline) on ToolPick-v0",
        description="Run a high-level checkpoint (SAC or phase clone), or a baseline, for N episodes of "
                    "hingelab/ToolPick-v0 "
                    "(deterministic actions, domain randomization as in training, seeds paired across "
                    "policies) and write each episode into the dataset --out, with a success table "
                    "(first attempt and within 200 steps, Wilson 95%% intervals, failure reasons: table.csv, "
                    "report.md) and one row per episode (episodes.csv).")
    high.add_argument("checkpoint", type=Path, nargs="?", default=None,
                      help="a high-level checkpoint of hingelab train high (a stable-baselines3 SAC zip or a phase "
                           "clone, or a residual over one) trained on ToolPick-v0 (or a run folder with model.zip, "
                           "or a run's checkpoints/step_N folder: the policy at that step; "
                           "default: the shipped assets/checkpoints/high_level.zip once there is one)")
    high.add_argument("--object", default="sphere",
                      help="object: sphere, cube, cylinder, tetrahedron, mesh:PATH or family:NAME[:SEED] (a new "
                           "object each episode from a procedural family: hingelab.sim.object_families) "
                           "(default sphere)")
    add_max_mesh_mb(high)
    high.add_argument("--size", type=finite_float, default=0.02,
                      help="object size in m; a family's size cap, 0.008 to 0.03 (default 0.02)")
    high.add_argument("--episodes", type=int, default=20, help="evaluation episodes (default 20)")
    high.add_argument("--out", type=Path, required=True, help="dataset folder to write (must be new or empty)")
    high.add_argument("--seed", type=seed_argument, default=0, help="seed of the episodes (default 0)")
    high.add_argument("--baseline", default=None, metavar="{" + ",".join(BASELINES["high"]) + "}",
                      help="evaluate a baseline instead of a checkpoint: heuristic (privileged, commands the "
                           "hinge), scripted (the heuristic's motion as latent goals over the low level), "
                           "scripted-observed (scripted, told the object's position by the policy's observation: "
                           "its noise and delay), scripted-perceived (scripted-observed that also reads its own "
                           "grip point and opening from the observed tool pose and z_bar: the demonstrator on exactly "
                           "the high level's observation), "
                           "scripted-feedback (the same without the object's size: one opening width, the hinge "
                           "closed by feedback on the perceived opening), random")
    high.add_argument("--low-level", default=None,
                      help="the frozen low level: policy (the shipped low-level policy), privileged, or a low-level "
                           "checkpoint (default: the one the checkpoint learned over; for baselines, policy)")
    high.add_argument("--perception", choices=("synthesized", "camera"), default="synthesized",
                      help="where the tool clouds come from: synthesized from the tool's model (default, as in "
                           "training) or the rendered depth camera through the camera cloud pipeline")
    add_object_perception(high, "; the estimators need --perception camera")
    add_object_noise(high)
    high.add_argument("--tool-position", choices=TOOL_POSITIONS, default=None,
                      help="the tool position the policy observes: observed (the tracked one, the paper's; it carries "
                           "the clouds' per-episode calibration error), anchored (the nominal in-hand position plus "
                           "the tracked change since the episode's first frame), relative (the whole pose's change "
                           "since the first frame on the nominal pose) or nominal (the nominal in-hand pose, no "
                           "tracking); default: what the checkpoint was "
                           "trained on")
    high.add_argument("--no-progress", action="store_true", help="no progress bar")
    high.add_argument("--resume", action="store_true",
                      help="continue a stopped evaluation (a full disk, a kill) in --out: its finished episodes are "
                           "kept, the rest run with their own seeds; the other settings must be the same")
    add_ray_argument(high)
    high.set_defaults(func=run_high)
    add_picks_parser(what)
    eval_perception.add_parser(what)


def add_picks_parser(what) -> None:
    picks = what.add_parser(
        "picks", help="a high-level policy on each of the pick table's 12 sets, and the pooled table",
        description="Run a high-level checkpoint (or a baseline) for N episodes on each set of the pick table (4 "
                    "shapes x 1.5, 2 and 2.5 cm, or --sets), each an `eval high` dataset in OUT/SHAPE_NNmm with "
                    "the same episode seeds as any other policy's at --seed, then pool them into OUT/picks.md and "
                    "picks.csv (first attempt and within 200 steps, Wilson 95%% intervals, the lowest set). "
                    "Tables of two policies on the same seed pair episode by episode: hingelab report --picks "
                    "OUT_A/*mm OUT_B/*mm --out DIR counts the episodes one picked and the other missed.")
    picks.add_argument("checkpoint", type=Path, nargs="?", default=None,
                       help="a high-level checkpoint (as for eval high; default: the shipped one)")
    picks.add_argument("--out", type=Path, required=True,
                       help="folder to write: one dataset per set and the pooled table (must be new or empty, or "
                            "an evaluation of the same settings with --resume)")
    picks.add_argument("--episodes", type=int, default=50, help="evaluation episodes per set (default 50)")
    picks.add_argument("--seed", type=seed_argument, default=0, help="seed of the episodes (default 0)")
    picks.add_argument("--sets", nargs="+", default=None, metavar="OBJECT:SIZE",
                       help="the sets, e.g. sphere:0.025 cube:0.015 (size in m), or object families with their size "
                            "cap, e.g. family:prism3:0.03 family:torus:0.03 (default: the pick table's 12)")
    picks.add_argument("--baseline", default=None, metavar="{" + ",".join(BASELINES["high"]) + "}",
                       help="evaluate a baseline instead of a checkpoint (as for eval high)")
    picks.add_argument("--low-level", default=None,
                       help="the frozen low level (as for eval high; default: the one the checkpoint learned over)")
    picks.add_argument("--tool-position", choices=TOOL_POSITIONS, default=None,
                       help="the tool position the policy observes (as for eval high; default: what the checkpoint "
                            "was trained on)")
    picks.add_argument("--jobs", type=int, default=1,
                       help="sets evaluated at once, each in its own process with one torch thread (default 1)")
    picks.add_argument("--no-progress", action="store_true", help="no progress bar")
    picks.add_argument("--resume", action="store_true",
                       help="continue a stopped evaluation in --out: finished sets are kept, a cut-off set goes on "
                            "from its last whole episode; the settings must be the same")
    picks.set_defaults(func=run_picks)


def check_baseline(name: str | None, level: str) -> None:
    """A ``--baseline`` that names no baseline of ``level`` is one line (the parser does not load the registry)."""
    from hingelab.policies.loading import baseline_names  # the policies' registry (torch): on run

    if name is not None and name not in baseline_names(level):
        raise ConfigError(f"--baseline {name}: not a {level}-level baseline; choose one of "
                          f"{', '.join(baseline_names(level))}")


def run_low(args: argparse.Namespace) -> int:
    from hingelab.rollouts.evaluation import evaluate_low  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, DATASET)
    check_baseline(args.baseline, "low")
    with folder_lock(args.out, args.argv):
        result = evaluate_low(args.checkpoint, out=args.out, baseline=args.baseline, episodes=args.episodes,
                              seed=args.seed, randomize=not args.no_randomize, perception=args.perception,
                              resume=args.resume, ray=args.ray, progress=not args.no_progress, command=args.argv)
    print(result.table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(result.summary)
    return 0


def run_high(args: argparse.Namespace) -> int:
    from hingelab.rollouts.evaluation import evaluate_high  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, DATASET)
    check_baseline(args.baseline, "high")
    with folder_lock(args.out, args.argv):
        result = evaluate_high(args.checkpoint, out=args.out, baseline=args.baseline, object=args.object,
                               size=args.size, episodes=args.episodes, seed=args.seed, low_level=args.low_level,
                               perception=args.perception, object_perception=args.object_perception, resume=args.resume,
                               ray=args.ray, object_noise=args.object_noise, object_noise_model=args.object_noise_model,
                               tool_position=args.tool_position, progress=not args.no_progress, command=args.argv)
    print(result.table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(result.summary)
    return 0


def run_picks(args: argparse.Namespace) -> int:
    from hingelab.out_dir import PICKS
    from hingelab.rollouts.pick_sets import evaluate_pick_sets  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, PICKS)
    check_baseline(args.baseline, "high")
    settings = {"baseline": args.baseline, "low_level": args.low_level, "tool_position": args.tool_position}
    command = command_line(args.argv)
    with folder_lock(args.out, args.argv):
        table = evaluate_pick_sets(args.checkpoint, out=args.out, sets=args.sets, episodes=args.episodes,
                                   seed=args.seed, jobs=args.jobs, resume=args.resume, progress=not args.no_progress,
                                   command=args.argv, report_command=command, **settings)
    pooled = table[table["object"] == "all"].iloc[0]
    print(f"{pooled['policy']} over {len(table) - 1} sets, {int(pooled['episodes'])} episodes: first attempt "
          f"{int(pooled['first_attempt_successes'])}/{int(pooled['episodes'])} = "
          f"{pooled['first_attempt_success_rate']:.3f} [{pooled['first_attempt_ci_low']:.3f}, "
          f"{pooled['first_attempt_ci_high']:.3f}], lowest set {pooled['lowest_set_first_attempt_success_rate']:.2f}; "
          f"within 200 steps {int(pooled['successes'])}. Tables: {args.out}/picks.md, picks.csv.")
    return 0
