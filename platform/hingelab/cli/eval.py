"""``hingelab eval WHAT CHECKPOINT``: run a trained policy and write an evaluation dataset.

``low``: the low-level policy on ToolShape-v0 toward reachable goals stratified over the
opening range; every episode is an MCAP episode in ``--out``; the report is the success
rate per goal region (thirds of the reachable opening range) with Wilson 95% intervals.
Success is the env's one verdict (ToolShape-v0: settled over the last 0.5 s), the episodes'
recorded ``success``, so ``hingelab report`` of ``--out`` counts the same episodes.

``high``: a high-level checkpoint (SAC or phase clone), or a baseline (heuristic, scripted, scripted-observed, scripted-feedback,
random), on ToolPick-v0
(``hingelab.rollouts.high_level``): success within 200 steps and at the first attempt,
attempts and failure reasons per episode; a table with Wilson 95% intervals (table.csv, report.md).

``perception``: the depth camera's perception against the synthesized clouds on the same poses
(``hingelab.cli.eval_perception``).
"""

from __future__ import annotations

import argparse
import json
from contextlib import contextmanager
from pathlib import Path

from hingelab.cli.options import add_ray_argument


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
    low.add_argument("--seed", type=int, default=0, help="seed of the goals and episodes (default 0)")
    low.add_argument("--baseline", choices=("hold-still", "synergy"), default=None,  # low_level_eval.REFERENCES
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
        description="Run a high-level checkpoint (SAC or phase clone), or a baseline, for N episodes of hingelab/ToolPick-v0 "
                    "(deterministic actions, domain randomization as in training, seeds paired across "
                    "policies) and write each episode into the dataset --out, with a success table "
                    "(first attempt and within 200 steps, Wilson 95%% intervals, failure reasons: table.csv, "
                    "report.md) and one row per episode (episodes.csv).")
    high.add_argument("checkpoint", type=Path, nargs="?", default=None,
                      help="a high-level checkpoint of hingelab train high (a stable-baselines3 SAC zip or a phase "
                           "clone) trained on ToolPick-v0 (or a run folder with model.zip; "
                           "default: the shipped assets/checkpoints/high_level.zip once there is one)")
    high.add_argument("--object", default="sphere", help="object shape (default sphere)")
    high.add_argument("--size", type=float, default=0.02, help="object size in m (default 0.02)")
    high.add_argument("--episodes", type=int, default=20, help="evaluation episodes (default 20)")
    high.add_argument("--out", type=Path, required=True, help="dataset folder to write (must be new or empty)")
    high.add_argument("--seed", type=int, default=0, help="seed of the episodes (default 0)")
    high.add_argument("--baseline", default=None,
                      choices=("heuristic", "scripted", "scripted-observed", "scripted-feedback", "random"),
                      help="evaluate a baseline instead of a checkpoint: heuristic (privileged, commands the "
                           "hinge), scripted (the heuristic's motion as latent goals over the low level), "
                           "scripted-observed (scripted, told the object's position by the policy's observation: "
                           "its noise and delay), "
                           "scripted-feedback (the same without the object's size: one opening width, the hinge "
                           "closed by feedback on the perceived opening), random")  # high_level_eval.BASELINES
    high.add_argument("--low-level", default=None,
                      help="the frozen low level: policy (the shipped low-level policy), privileged, or a low-level "
                           "checkpoint (default: the one the checkpoint learned over; for baselines, policy)")
    high.add_argument("--perception", choices=("synthesized", "camera"), default="synthesized",
                      help="where the tool clouds come from: synthesized from the tool's model (default, as in "
                           "training) or the rendered depth camera through the camera cloud pipeline")
    high.add_argument("--no-progress", action="store_true", help="no progress bar")
    high.add_argument("--resume", action="store_true",
                      help="continue a stopped evaluation (a full disk, a kill) in --out: its finished episodes are "
                           "kept, the rest run with their own seeds; the other settings must be the same")
    add_ray_argument(high)
    high.set_defaults(func=run_high)
    from hingelab.cli import eval_perception

    eval_perception.add_parser(what)


def run_low(args: argparse.Namespace) -> int:
    from hingelab.envs.low_level import PolicyLowLevel
    from hingelab.policies.low_level import SHIPPED_LOW_LEVEL
    from hingelab.episodes import create_dataset
    from hingelab.errors import ConfigError
    from hingelab.envs.tool_shape import SETTLE_STEPS
    from hingelab.rollouts.low_level import evaluation_env_arguments
    from hingelab.rollouts.journal import prepare_resume
    from hingelab.policies import load_policy
    from hingelab.rollouts.low_level import evaluate_sampled_goals, make_eval_env, region_table

    if args.baseline and args.checkpoint is not None:
        raise ConfigError("give a checkpoint or --baseline, not both")
    if args.checkpoint is None and not args.baseline:
        args.checkpoint = SHIPPED_LOW_LEVEL
    if args.episodes < 1:
        raise ConfigError("--episodes must be at least 1")
    model = None if args.baseline else PolicyLowLevel(args.checkpoint).model
    label = args.baseline or str(args.checkpoint)
    provenance = getattr(model, "hingelab_provenance", {}) or {}
    # the env the checkpoint was trained on (its record), on held-out goals: not its training goal band
    env_args = {**(evaluation_env_arguments(model) if model is not None else {}), "randomize": not args.no_randomize}
    if args.perception != "synthesized":  # recorded only when it differs: older evaluations resume unchanged
        env_args["perception"] = args.perception
    config = {"checkpoint": label, "episodes": args.episodes, "env": env_args,
              "checkpoint_git_commit": provenance.get("git_commit", "unknown")}
    # a run's model.zip and best_model.zip: the run folder names the dataset
    name = f"eval-{args.baseline}" if args.baseline else f"eval-{args.checkpoint.parent.name}-{args.checkpoint.stem}"
    if args.perception != "synthesized":  # a report of both sets of one policy tells them apart by name
        name += f"-{args.perception}"
    journal = prepare_resume(args.out, {**config, "seed": args.seed}, args.resume)
    if not args.resume:
        create_dataset(args.out, name=name, source="low_level_evaluation", config={**config, "seed": args.seed},
                       seed=args.seed, description="hingelab eval low: a low-level policy toward reachable goals")
    env = make_eval_env(env_args, record_dir=None if args.ray else args.out)  # --ray: the tasks record
    unwrapped = env.unwrapped
    policy = load_policy(args.baseline, env=env) if args.baseline else model
    with stop_cleanly_on_a_full_disk(args, journal):
        if args.ray:
            from hingelab.rollouts.on_ray import evaluate_low_on_ray
            from hingelab.rollouts.low_level import sampled_goals

            goals = sampled_goals(unwrapped.calibration, unwrapped.reachable_range, args.episodes, args.seed)
            episodes = evaluate_low_on_ray(goals, env_args, args.out, args.checkpoint, args.baseline, journal,
                                           args.ray, progress=not args.no_progress)
        else:
            episodes = evaluate_sampled_goals(policy, env, args.episodes, args.seed, progress=not args.no_progress,
                                              journal=journal)
    env.close()
    from hingelab.analysis.documents import markdown_table

    table = region_table(episodes)
    episodes.to_csv(args.out / "episodes.csv", index=False)
    journal.finish()
    table.to_csv(args.out / "regions.csv", index=False)
    (args.out / "report.md").write_text(
        f"# Low-level evaluation of {label}\n\n{args.episodes} episodes, seed {args.seed}, "
        f"env {json.dumps(env_args)}; success threshold {unwrapped.success_threshold:.4f} (latent distance "
        f"of 2 mm tip gap); regions are thirds of the reachable opening range "
        f"{unwrapped.reachable_range[0]:.3f}..{unwrapped.reachable_range[1]:.3f} rad. `success` (the env's "
        f"verdict, `{unwrapped.success_verdict}`, recorded as each episode's success): z_bar averaged over the last "
        f"{SETTLE_STEPS} steps (0.5 s) within the threshold; `last_step_` (secondary, not counted as success): "
        f"z_bar of the last step alone within it; `tip_gap_error_mm`: the privileged tip gap over the last "
        f"{SETTLE_STEPS} steps against the gap of the goal's calibrated opening.\n\n"
        + markdown_table(table.round(3)) + "\n")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    overall = table[table["goal_region"] == "all"].iloc[0]
    print(f"Evaluated {label} on {args.episodes} reachable goals: success (settled over the last {SETTLE_STEPS} "
          f"steps, the episodes' recorded verdict) {int(overall['successes'])}/{args.episodes} = "
          f"{overall['success_rate']:.2f} [{overall['ci_low']:.2f}, {overall['ci_high']:.2f}] (with the tool "
          f"drifting under 1 cm {overall['success_and_drift_under_1cm']:.2f}); secondary, the last step alone "
          f"{overall['last_step_success_rate']:.2f}; median tip-gap error {overall['tip_gap_error_mm_median']:.1f} mm. "
          f"Dataset, episodes.csv, regions.csv, report.md in {args.out}.")
    return 0


@contextmanager
def stop_cleanly_on_a_full_disk(args: argparse.Namespace, journal):
    """A full disk during an evaluation: one line (folder, free space, episodes kept), resumable."""
    from hingelab.disk_full import disk_full_error, is_disk_full
    from hingelab.rollouts.journal import command_line

    try:
        yield
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        command = command_line(getattr(args, "argv", None))
        raise disk_full_error(args.out, len(journal.rows), args.episodes, command) from exc


def run_high(args: argparse.Namespace) -> int:
    from hingelab.analysis.documents import markdown_table
    from hingelab.rollouts.journal import prepare_resume
    from hingelab.episodes import create_dataset
    from hingelab.errors import ConfigError
    from hingelab.rollouts import high_level as H

    if args.baseline and args.checkpoint is not None:
        raise ConfigError("give a checkpoint or --baseline, not both")
    if args.checkpoint is None and not args.baseline:
        from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL

        if not SHIPPED_HIGH_LEVEL.exists():
            raise ConfigError(f"there is no shipped high-level policy ({SHIPPED_HIGH_LEVEL}) yet: give a SAC "
                              "checkpoint trained on ToolPick-v0 (hingelab train high), or --baseline "
                              "heuristic|scripted|random")
        args.checkpoint = SHIPPED_HIGH_LEVEL
    if args.episodes < 1:
        raise ConfigError("--episodes must be at least 1")
    if args.baseline:
        policy, label, observe_extent = load_policy(args.baseline), args.baseline, False
        # the heuristic bypasses the low level: privileged, as in hingelab generate heuristic
        low_level = "privileged" if args.baseline == "heuristic" else (args.low_level or "policy")
    else:
        from hingelab.policies.high_level import check_context, load_high_level_checkpoint, observes_extent

        model = load_high_level_checkpoint(args.checkpoint)
        recorded = getattr(model, "hingelab_provenance", None) or {}
        low_level = args.low_level or recorded.get("low_level", "policy")
        check_context(model, args.checkpoint, low_level)
        policy, label = ModelPolicy(model), str(args.checkpoint)
        observe_extent = observes_extent(model)
    # bad object or low level: an error before files
    H.make_eval_env(args.object, args.size, low_level, observe_extent=observe_extent,
                    perception=args.perception).close()
    config = {"policy": label, "object": args.object, "size": args.size, "episodes": args.episodes,
              "low_level": low_level, "observe_extent": observe_extent,
              "seeds": f"{H.SEED_BASE} + seed * {H.SEED_STRIDE} + episode"}
    if args.perception != "synthesized":  # recorded only when it differs: older evaluations resume unchanged
        config["perception"] = args.perception
    name = f"eval-high-{args.baseline or Path(args.checkpoint).stem}"
    if args.perception != "synthesized":
        name += f"-{args.perception}"
    journal = prepare_resume(args.out, {**config, "seed": args.seed}, args.resume)
    if not args.resume:
        create_dataset(args.out, name=name, source="high_level_evaluation", config={**config, "seed": args.seed},
                       seed=args.seed, description=f"hingelab eval high: {label} on ToolPick-v0, {args.object} "
                                                   f"{args.size * 100:g} cm")
    env_options = {"object": args.object, "size": args.size, "low_level": low_level, "observe_extent": observe_extent,
                   "extra_metadata": {"policy": label, "low_level": low_level, "perception": args.perception},
                   "perception": args.perception}
    if args.ray:
        from hingelab.rollouts.on_ray import evaluate_high_on_ray

        with stop_cleanly_on_a_full_disk(args, journal):
            episodes = evaluate_high_on_ray(args.episodes, args.seed, env_options, args.out, args.checkpoint,
                                            args.baseline, journal, args.ray, progress=not args.no_progress)
    else:
        env = H.make_eval_env(record_dir=args.out, **env_options)
        try:
            with stop_cleanly_on_a_full_disk(args, journal):
                episodes = H.evaluate(policy, env, args.episodes, args.seed, progress=not args.no_progress,
                                      label=f"eval high {label}", journal=journal)
        finally:
            env.close()
    table = H.success_table(episodes, args.object, args.size)
    episodes.to_csv(args.out / "episodes.csv", index=False)
    journal.finish()
    table.to_csv(args.out / "table.csv", index=False)
    row = table.iloc[0]
    failures = ", ".join(f"{r} {int(row[f'failures_{r}'])}" for r in H.FAILURE_REASONS if row[f"failures_{r}"])
    summary = (f"Evaluated {label} (low level {low_level}) on {args.episodes} episodes of ToolPick-v0 with a "
               f"{args.object} of {args.size * 100:g} cm, {args.perception} perception, seed {args.seed}: success "
               f"within 200 steps (object within "
               f"1 cm of the target, the episodes' recorded verdict) {int(row['successes'])}/{args.episodes} = "
               f"{row['success_rate']:.2f} [{row['ci_low']:.2f}, {row['ci_high']:.2f}], at the first attempt "
               f"{int(row['first_attempt_successes'])}/{args.episodes} = {row['first_attempt_success_rate']:.2f} "
               f"[{row['first_attempt_ci_low']:.2f}, {row['first_attempt_ci_high']:.2f}], mean attempts "
               f"{row['mean_attempts']:.2f}; failures: {failures or 'none'}. Dataset, episodes.csv, table.csv, "
               f"report.md in {args.out}.")
    (args.out / "report.md").write_text(
        f"# High-level evaluation of {label}\n\n{args.episodes} episodes, seed {args.seed} (episode i reset with "
        f"seed {H.SEED_BASE} + {args.seed} * {H.SEED_STRIDE} + i, the same for every policy), low level "
        f"{low_level}. `success`: the env's verdict, object within 1 cm of the target within 200 steps; "
        f"`first_attempt_`: that before any grasp was lost; intervals are Wilson 95%; failure reasons as in "
        f"`hingelab.rollouts.high_level`.\n\n" + markdown_table(table.round(3)) + "\n\n" + summary + "\n")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(summary)
    return 0
