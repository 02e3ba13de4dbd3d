"""``hingelab diagnose WHAT --out DIR``: checks of the high level's learning problem that can fail.

``reward``: is finishing worth more to a critic than lingering near the target, under each reward mode
(``hingelab.rollouts.reward_diagnostic``). ``noise``: how much exploration noise each action dimension
tolerates before the scripted demonstrator fails (``hingelab.rollouts.noise_tolerance``). ``object-estimate``: how far
each estimator of the object's position from the depth camera lands from the truth
(``hingelab.rollouts.object_estimate_errors``). ``object-noise-fit``: a model of those errors fitted on its frames
(``hingelab.rollouts.object_noise_fit``). ``grasp``: whether where the tips hold the object at the lift
explains a policy's failed picks (``hingelab.rollouts.grasp_offsets``). ``grasp-observability``: whether the
policy's observation can see that grasp offset (``hingelab.rollouts.grasp_observability``)."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from hingelab.arguments import finite_float
from hingelab.cli.names import BIAS_LEVELS, NOISE_LEVELS
from hingelab.out_dir import REPORT, check_out
from hingelab.provenance import code_version, require_clean_for
from hingelab.seeds import seed_argument
from hingelab.tasks import HIGH_LEVEL_ACTION_NAMES


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("diagnose",
                              help="diagnostics of the high level's learning problem (reward, noise, residual, bias, "
                                   "object-estimate, grasp, families, tool-position)",
                              description="Diagnostics that can fail: what the high-level reward pays for "
                                          "finishing against lingering, how much exploration noise and constant "
                                          "offset each action dimension tolerates, why a fine-tuned residual "
                                          "picks less than its base, how far the depth camera's object "
                                          "estimate is from the truth, a model of that error fitted for "
                                          "training without rendering, where the tips hold the object "
                                          "when a policy's picks fail, which objects of a family it misses, and "
                                          "whether the tool clouds' calibration error costs the picks.")
    what = p.add_subparsers(title="diagnostics", metavar="WHAT", required=True)
    reward = what.add_parser(
        "reward", help="the value of succeeding against hovering 1.1 cm short, under each reward mode",
        description="The scripted demonstrator picks the object from N starts, once as it does and once holding "
                    "it 1.1 cm below the target until the time limit; for the paper's reward and the absorbing "
                    "one, the value a critic learns at the decision point (the object first within 2 cm of the "
                    "target). Writes reward_diagnostic.md, summary.csv and episodes.csv into --out.")
    reward.add_argument("--episodes", type=int, default=10, help="starts (pairs of episodes; default 10)")
    reward.add_argument("--seed", type=seed_argument, default=9100,
                        help="seed of the starts, eval high's stream (default 9100)")
    reward.add_argument("--gamma", type=finite_float, default=0.98,
                        help="the critic's discount (default 0.98, SAC's here)")
    reward.set_defaults(func=run_reward)
    noise = what.add_parser(
        "noise", help="exploration noise each action dimension tolerates (the scripted demonstrator)",
        description="The scripted demonstrator over the shipped low level with Gaussian noise on one executed "
                    "action dimension at a time (latent goal 0 and 1, hand velocity x, y, z), --episodes per level "
                    "from the same starts; a table of successes and tool drops and the tolerated level per "
                    "dimension. Writes noise_tolerance.md and noise_tolerance.csv into --out.")
    noise.add_argument("--episodes", type=int, default=20, help="episodes per level (default 20)")
    noise.add_argument("--levels", type=finite_float, nargs="+", default=list(NOISE_LEVELS),
                       metavar="STD", help="noise stds in action units (default "
                                           f"{' '.join(map(str, NOISE_LEVELS))})")
    noise.add_argument("--seed", type=seed_argument, default=9200,
                       help="seed of the starts, eval high's stream (default 9200)")
    noise.set_defaults(func=run_noise)
    residual = what.add_parser(
        "residual", help="why a fine-tuned residual picks less than its base: the reward or the learner",
        description="Runs the residual policy, its base, and the residual with each action group zeroed (latent "
                    "goal, hand velocity xy, hand velocity z) from the same --episodes starts; per arm success and "
                    "the true discounted value of the start state. If the residual picks less and its true value "
                    "falls too, the learner failed at its own objective (the critics misled the actor); if its "
                    "value rises, the reward pays for what costs picks. Writes residual_diagnostic.md, summary.csv "
                    "and episodes.csv into --out.")
    residual.add_argument("checkpoint", type=Path,
                          help="a residual policy (RUNDIR/model.zip) or a run's checkpoint RUNDIR/checkpoints/step_N")
    residual.add_argument("--episodes", type=int, default=30, help="starts per arm (default 30)")
    residual.add_argument("--seed", type=seed_argument, default=100,
                          help="seed of the starts, eval high's stream (default 100; not the run's own)")
    residual.add_argument("--gamma", type=finite_float, default=None, help="discount (default: the run's)")
    residual.set_defaults(func=run_residual)
    bias = what.add_parser(
        "bias", help="the consistent offset each action dimension of a policy tolerates (a residual's reach)",
        description="A policy (default the shipped clone, the residual learner's base) with a constant offset, "
                    "+level and -level, on one executed action dimension at a time, --episodes from the same "
                    "starts per offset; successes, tool drops and the level each dimension tolerates. A residual "
                    "is an offset the base executes step after step: its reach should stay near this. Writes "
                    "bias_tolerance.md and bias_tolerance.csv into --out.")
    bias.add_argument("checkpoint", type=Path, nargs="?", default=None,
                      help="a high-level policy (default: the shipped assets/checkpoints/high_level.zip)")
    bias.add_argument("--episodes", type=int, default=30, help="episodes per offset (default 30)")
    bias.add_argument("--levels", type=finite_float, nargs="+", default=list(BIAS_LEVELS), metavar="L",
                      help="offset sizes in action units, each tried with both signs (default "
                           f"{' '.join(map(str, BIAS_LEVELS))})")
    bias.add_argument("--dimensions", nargs="+", default=list(HIGH_LEVEL_ACTION_NAMES),
                      choices=HIGH_LEVEL_ACTION_NAMES, metavar="DIM",
                      help=f"action dimensions to offset (default all: {' '.join(HIGH_LEVEL_ACTION_NAMES)})")
    bias.add_argument("--seed", type=seed_argument, default=100,
                      help="seed of the starts, eval high's stream (default 100)")
    bias.set_defaults(func=run_bias)
    for sub in (reward, noise, residual, bias):
        sub.add_argument("--object", default="sphere", help="object shape (default sphere, the training object)")
        sub.add_argument("--size", type=finite_float, default=0.02, help="object width in m (default 0.02)")
    objects = what.add_parser(
        "object-estimate", help="the object's position from the depth camera: each estimator's error",
        description="The stand-in's scene with each test shape (sphere, cube, cylinder, tetrahedron) and size "
                    "(1.5, 2, 2.5 cm) at --placements random spots; --frames depth frames per spot with depth "
                    "noise and segmentation errors; the error of each object estimator (the paper's centroid, "
                    "ray-corrected, sphere fit, and a temporal median of each) against the true centre. Writes "
                    "object_estimate.md, summary.csv, frames.csv and frame.png into --out.")
    objects.add_argument("--placements", type=int, default=20, help="spots per shape and size (default 20)")
    objects.add_argument("--frames", type=int, default=5, help="frames per spot (default 5)")
    objects.add_argument("--seed", type=seed_argument, default=0,
                         help="seed of the spots, noise and mask errors (default 0)")
    objects.set_defaults(func=run_object_estimate)
    grasp = what.add_parser(
        "grasp", help="where the tips hold the object at the lift, against the demonstrator's picks",
        description="For each episode of the eval high datasets given, the tips' midpoint minus the object's centre "
                    "at the first lift command (hand_base frame, mm); per axis, the episodes inside and outside the "
                    "range where --reference (the demonstrator on the same seeds, e.g. eval high --baseline "
                    "scripted-observed) picked, and how often each failed at the first attempt: whether the grasp "
                    "pose explains the failures. Writes grasp_offsets.md, summary.csv and episodes.csv into --out.")
    grasp.add_argument("datasets", type=Path, nargs="+", metavar="DATASET", help="eval high dataset folders")
    grasp.add_argument("--reference", type=Path, required=True,
                       help="the demonstrator's eval high dataset whose first-attempt picks set the ranges")
    grasp.set_defaults(func=run_grasp)
    families = what.add_parser(
        "families", help="which objects of a family a policy misses: picks by kind and drawn size",
        description="For the eval high / eval picks datasets of family:NAME objects given (each episode records its "
                    "draw), first-attempt picks per policy split by kind and by the drawn size, with Wilson 95% "
                    "intervals, each kind's failures by reason, and a verdict naming the size bin and the kind with "
                    "the lowest rate and whether it lies below the others' interval. Writes families.md, "
                    "summary.csv, failures.csv and episodes.csv into --out.")
    families.add_argument("datasets", type=Path, nargs="+", metavar="DATASET",
                          help="eval high dataset folders of family:NAME objects (e.g. eval picks' DIR/family_*)")
    families.add_argument("--size-bins", type=finite_float, nargs="+", default=[14.0, 20.0, 26.0], metavar="MM",
                          help="edges of the size bins in mm (default 14 20 26: below, within and above the pick "
                               "table's 15-25 mm sets)")
    families.set_defaults(func=run_families)
    seeing = what.add_parser(
        "grasp-observability", help="how much of the grasp offset the policy's observation can see",
        description="At each episode's first lift command, the true grasp offset (the tips' midpoint minus the "
                    "object's centre, hand_base frame, mm) regressed by least squares on the policy's observation, "
                    "on the observation with the true tool pose, and with the true object too; held-out R^2 per "
                    "axis: whether a policy on the observation can see the offset that fails its grasps. Reads "
                    "ToolPick-v0 datasets with /sim/privileged (a training run's RUNDIR/dataset, eval high). Writes "
                    "observability.md and observability.csv into --out.")
    seeing.add_argument("datasets", type=Path, nargs="+", metavar="DATASET",
                        help="ToolPick-v0 dataset folders (together at least 30 episodes that lift)")
    seeing.add_argument("--seed", type=seed_argument, default=0, help="seed of the held-out split (default 0)")
    seeing.set_defaults(func=run_grasp_observability)
    fitted = what.add_parser(
        "object-noise-fit", help="a model of the camera's object estimate (bias, noise, dropout) for ToolPick-v0",
        description="Fits hingelab.perception.object_noise_model on object-estimate's frames.csv: per estimator, "
                    "shape and size, the error's bias and noise along and across the viewing ray, outliers, "
                    "dropouts and the extent's error; samples it against the measured frames. Writes "
                    "object_noise_model.json, residuals.csv and residuals.md into --out.")
    fitted.add_argument("--frames", type=Path, default=Path("analysis/objects/frames.csv"),
                        help="frames.csv of hingelab diagnose object-estimate (default analysis/objects/frames.csv)")
    fitted.add_argument("--seed", type=seed_argument, default=0, help="seed of the residuals' sampling (default 0)")
    fitted.set_defaults(func=run_object_noise_fit)
    tool = what.add_parser(
        "tool-position", help="whether the tool clouds' calibration error costs a policy its picks",
        description="One policy trained on the observed tool position on the same reset seeds three times: the "
                    "paper's synthesized clouds with their per-episode pose error (up to 2 cm and 30 degrees, a "
                    "calibration error), the same clouds without that error, and the paper's clouds with ToolPick-v0's "
                    "anchored tool position (the nominal in-hand position plus the tracked change). First-attempt "
                    "picks per arm and paired against the first: what the error costs and what anchoring wins back. "
                    "Writes tool_position.md, summary.csv and episodes.csv into --out.")
    tool.add_argument("checkpoint", type=Path,
                      help="a high-level checkpoint trained on the observed tool position, e.g. "
                           "analysis/high-level/previous-shipped/high_level_cbc73bd.zip (the shipped one until "
                           "2026-12-07; the shipped one now observes the relative pose)")
    tool.add_argument("--object", default="tetrahedron", help="object shape (default tetrahedron)")
    tool.add_argument("--size", type=finite_float, default=0.015, help="object width in m (default 0.015)")
    tool.add_argument("--episodes", type=int, default=25, help="episodes per arm (default 25)")
    tool.add_argument("--seed", type=seed_argument, default=1350, help="exploration seed of the resets (default 1350)")
    tool.set_defaults(func=run_tool_position)
    for sub in (reward, noise, residual, bias, objects, fitted, grasp, families, seeing, tool):
        sub.add_argument("--out", type=Path, required=True, help="report folder, e.g. analysis/high-level/reward")
        sub.add_argument("--allow-dirty", action="store_true",
                         help="write under analysis/ from uncommitted code (the report then says so)")
        sub.add_argument("--no-progress", action="store_true", help="no progress bar")


def _command(args, verb: str, options: list[str]) -> str:
    words = ["hingelab", "diagnose", verb, *options, "--out", str(args.out)]
    return shlex.join(words) + f" (git {code_version()['git_commit'][:7]})"


def run_reward(args: argparse.Namespace) -> int:
    from hingelab.rollouts import reward_diagnostic  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose reward")
    rows = reward_diagnostic.diagnose(args.episodes, args.seed, args.gamma, args.object, args.size,
                                      progress=not args.no_progress)
    summary = reward_diagnostic.summarize(rows)
    options = ["--episodes", str(args.episodes), "--seed", str(args.seed), "--gamma", f"{args.gamma:g}",
               "--object", args.object, "--size", f"{args.size:g}"]
    path = reward_diagnostic.write_report(rows, summary, args.out, _command(args, "reward", options), args.gamma)
    for s in summary:
        print(f"{s['mode']}: succeeding {s['success_value_at_decision']:.1f}, hovering "
              f"{s['hover_value_at_decision']:.1f} at the decision point; succeeding worth more on "
              f"{s['finishing_pays_more']} of {s['pairs']} starts")
    print(f"wrote {path}")
    return 0


def run_residual(args: argparse.Namespace) -> int:
    from hingelab.rollouts import residual_diagnostic  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose residual")
    rows, gamma = residual_diagnostic.diagnose(args.checkpoint, args.object, args.size, args.episodes, args.seed,
                                               args.gamma, progress=not args.no_progress)
    summary = residual_diagnostic.summarize(rows)
    options = [str(args.checkpoint), "--episodes", str(args.episodes), "--seed", str(args.seed), "--object",
               args.object, "--size", f"{args.size:g}"] + (["--gamma", f"{args.gamma:g}"] if args.gamma else [])
    path = residual_diagnostic.write_report(rows, summary, args.out, _command(args, "residual", options), gamma)
    for s in summary:
        print(f"{s['arm']}: {s['successes']}/{s['episodes']} picked, v0 {s['v0']:.1f}")
    print(residual_diagnostic.verdict(summary))
    print(f"wrote {path}")
    return 0


def run_tool_position(args: argparse.Namespace) -> int:
    from hingelab.rollouts import tool_position_diagnostic as D  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose tool-position")
    rows = D.diagnose(args.checkpoint, args.object, args.size, args.episodes, args.seed, progress=not args.no_progress)
    summary = D.summarize(rows)
    options = [str(args.checkpoint)] + [
        "--object", args.object, "--size", f"{args.size:g}", "--episodes", str(args.episodes), "--seed", str(args.seed)]
    policy = f"`{args.checkpoint}`"
    path = D.write_report(rows, summary, args.out, _command(args, "tool-position", options), policy, args.object,
                          args.size)
    for s in summary:
        print(f"{s['arm']}: {s['first_attempt']}/{s['episodes']} at the first attempt")
    print(D.verdict(summary))
    print(f"wrote {path}")
    return 0


def run_bias(args: argparse.Namespace) -> int:
    from hingelab.rollouts import bias_tolerance  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose bias")
    rows = bias_tolerance.measure(args.checkpoint, args.episodes, args.levels, args.dimensions, args.seed,
                                  args.object, args.size, progress=not args.no_progress)
    options = ([str(args.checkpoint)] if args.checkpoint else []) + [
        "--episodes", str(args.episodes), "--levels", *(f"{v:g}" for v in args.levels), "--dimensions",
        *args.dimensions, "--seed", str(args.seed), "--object", args.object, "--size", f"{args.size:g}"]
    policy = f"`{args.checkpoint}`" if args.checkpoint else "The shipped high level (assets/checkpoints/high_level.zip)"
    path = bias_tolerance.write_report(rows, args.out, _command(args, "bias", options), policy)
    for name, level in bias_tolerance.tolerances(rows).items():
        print(f"{name}: tolerates an offset of {level:g}")
    print(f"wrote {path}")
    return 0


def run_noise(args: argparse.Namespace) -> int:
    from hingelab.rollouts import noise_tolerance  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose noise")
    rows = noise_tolerance.measure(args.episodes, args.levels, args.seed, args.object, args.size,
                                   progress=not args.no_progress)
    options = ["--episodes", str(args.episodes), "--levels", *(f"{v:g}" for v in args.levels), "--seed",
               str(args.seed), "--object", args.object, "--size", f"{args.size:g}"]
    path = noise_tolerance.write_report(rows, args.out, _command(args, "noise", options))
    for name, level in noise_tolerance.tolerances(rows).items():
        print(f"{name}: tolerates std {level:g}")
    print(f"wrote {path}")
    return 0


def run_object_estimate(args: argparse.Namespace) -> int:
    from hingelab.rollouts import object_estimate_errors  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose object-estimate")
    rows, picture = object_estimate_errors.measure(args.placements, args.frames, args.seed,
                                                   progress=not args.no_progress)
    summary = object_estimate_errors.summarize(rows)
    options = ["--placements", str(args.placements), "--frames", str(args.frames), "--seed", str(args.seed)]
    path = object_estimate_errors.write_report(rows, summary, picture, args.out,
                                               _command(args, "object-estimate", options), args.placements,
                                               args.frames)
    for s in summary:
        if s["shape"] == "all":
            print(f"{s['estimator']}: median {s['median_mm']:.1f} mm, 95th percentile {s['p95_mm']:.1f} mm, "
                  f"ray bias {s['ray_bias_median_mm']:+.1f} mm ({s['flagged']} flagged)")
    print(f"wrote {path}")
    return 0


def run_grasp(args: argparse.Namespace) -> int:
    from hingelab.rollouts import grasp_offsets  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose grasp")
    ranges = grasp_offsets.reference_ranges(grasp_offsets.episode_rows(args.reference))
    rows = [row for root in args.datasets for row in grasp_offsets.episode_rows(root)]
    summary = grasp_offsets.summarize(rows, ranges)
    options = [str(d) for d in args.datasets] + ["--reference", str(args.reference)]
    path = grasp_offsets.write_report(rows, summary, args.out, _command(args, "grasp", options), str(args.reference))
    for name in dict.fromkeys(r["dataset"] for r in rows):
        print(grasp_offsets.verdict(summary, name))
    print(f"wrote {path}")
    return 0


def run_families(args: argparse.Namespace) -> int:
    from hingelab.rollouts import family_breakdown  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose families")
    rows = [row for root in args.datasets for row in family_breakdown.episode_rows(root)]
    summary = family_breakdown.summarize(rows, args.size_bins)
    options = [str(d) for d in args.datasets] + ["--size-bins", *(f"{e:g}" for e in args.size_bins)]
    path = family_breakdown.write_report(rows, summary, args.out, _command(args, "families", options))
    for policy in dict.fromkeys(r["policy"] for r in rows):
        print(family_breakdown.verdict(summary, policy))
    print(f"wrote {path}")
    return 0


def run_object_noise_fit(args: argparse.Namespace) -> int:
    from hingelab.rollouts import object_noise_fit  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose object-noise-fit")
    options = ["--frames", str(args.frames), "--seed", str(args.seed)]
    path, model, table = object_noise_fit.fit_and_report(args.frames, args.out, args.seed,
                                                         _command(args, "object-noise-fit", options), code_version())
    for r in table:
        if r["shape"] == "all":
            print(f"{r['estimator']}: 95th percentile {r['measured_p95_mm']:.1f} mm measured, {r['model_p95_mm']:.1f} "
                  f"mm by the model; ray bias {r['measured_ray_mm']:+.1f} / {r['model_ray_mm']:+.1f} mm")
    print(f"wrote {path}")
    return 0


def run_grasp_observability(args: argparse.Namespace) -> int:
    from hingelab.rollouts import grasp_observability  # on run: the parser stays light (hingelab.cli)

    check_out(args.out, REPORT)
    require_clean_for(args.out, args.allow_dirty, "hingelab diagnose grasp-observability")
    rows = grasp_observability.measure(args.datasets, args.seed)
    options = [str(d) for d in args.datasets] + ["--seed", str(args.seed)]
    path = grasp_observability.write_report(rows, args.out, _command(args, "grasp-observability", options))
    for axis in ("x", "y", "z"):
        print(grasp_observability.verdict(rows, axis))
    print(f"wrote {path}")
    return 0
