"""``hingelab eval WHAT CHECKPOINT``: run a trained policy and write an evaluation dataset.

``low``: the low-level policy on ToolShape-v0 toward reachable goals stratified over the
opening range; every episode is an MCAP episode in ``--out``; the report is the success
rate per goal region (thirds of the reachable opening range) with Wilson 95% intervals.
Success is the env's one verdict (ToolShape-v0: settled over the last 0.5 s), the episodes'
recorded ``success``, so ``hingelab report`` of ``--out`` counts the same episodes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


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
    low.add_argument("--no-progress", action="store_true", help="no progress bar")
    low.set_defaults(func=run_low)


def run_low(args: argparse.Namespace) -> int:
    from hingelab.envs.low_level import SHIPPED_LOW_LEVEL, PolicyLowLevel
    from hingelab.envs.rewards import LowLevelRewardConfig
    from hingelab.episodes import create_dataset
    from hingelab.errors import ConfigError
    from hingelab.envs.tool_shape import SETTLE_STEPS
    from hingelab.learning.low_level_eval import evaluate_sampled_goals, make_eval_env, reference_policy, region_table

    if args.baseline and args.checkpoint is not None:
        raise ConfigError("give a checkpoint or --baseline, not both")
    if args.checkpoint is None and not args.baseline:
        args.checkpoint = SHIPPED_LOW_LEVEL
    if args.episodes < 1:
        raise ConfigError("--episodes must be at least 1")
    if args.out.exists() and any(args.out.iterdir()):
        raise ConfigError(f"{args.out} is not empty; evaluate into a new folder")
    model = None if args.baseline else PolicyLowLevel(args.checkpoint).model
    label = args.baseline or str(args.checkpoint)
    provenance = getattr(model, "hingelab_provenance", {}) or {}
    trained = provenance.get("config", {})
    env_args = {"use_effort": trained.get("use_effort", True), "randomize": not args.no_randomize,
                "effort_weight": trained.get("effort_weight", LowLevelRewardConfig().c2),
                "drift_weight": trained.get("drift_weight", 0.0),
                "max_episode_steps": trained.get("max_episode_steps", 50)}
    config = {"checkpoint": label, "episodes": args.episodes, "env": env_args,
              "checkpoint_git_commit": provenance.get("git_commit", "unknown")}
    # a run's model.zip and best_model.zip: the run folder names the dataset
    name = f"eval-{args.baseline}" if args.baseline else f"eval-{args.checkpoint.parent.name}-{args.checkpoint.stem}"
    create_dataset(args.out, name=name, source="low_level_evaluation", config=config,
                   seed=args.seed, description="hingelab eval low: a low-level policy toward reachable goals")
    env = make_eval_env(env_args, record_dir=args.out)
    unwrapped = env.unwrapped
    policy = reference_policy(args.baseline, env) if args.baseline else model
    episodes = evaluate_sampled_goals(policy, env, args.episodes, args.seed, progress=not args.no_progress)
    env.close()
    from hingelab.analysis.documents import markdown_table

    table = region_table(episodes)
    episodes.to_csv(args.out / "episodes.csv", index=False)
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
