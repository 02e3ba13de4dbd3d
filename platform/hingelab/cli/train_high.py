"""``hingelab train high`` and ``hingelab train flat``: the high-level policy over the frozen low
level (ToolPick-v0) and the flat baseline (ToolPickFlat-v0), on the training core."""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.cli.train import add_run_arguments


def _add(learners, name: str, config_class, help_text: str, description: str, default_out: str,
         skip: tuple = ()) -> None:
    from hingelab.learning.run_config import add_config_arguments

    p = learners.add_parser(name, help=help_text, description=description)
    add_config_arguments(p, config_class, skip=skip)
    add_run_arguments(p, default_out)
    p.set_defaults(func=run_high, config_class=config_class, default_out=default_out)


# the demonstrations' flags: the heuristic's demos are not in the flat action space
FLAT_SKIPS = ("from_datasets", "demo_bc_weight", "bc_pretrain_updates", "demo_q_filter", "prior_episodes",
              "prior_source", "demo_share", "demo_actions", "demo_lookahead", "learner", "clone_updates",
              "clone_batch_size", "clone_learning_rate", "clone_members", "prior_action_noise")


def add_high_parser(learners) -> None:
    from hingelab.learning.high_level_config import HighLevelTrainConfig

    _add(learners, "high", HighLevelTrainConfig,
         "the high-level policy: SAC picking with the tweezer over the frozen low level (ToolPick-v0)",
         "Train the high-level SAC policy on hingelab/ToolPick-v0 (latent goal for the frozen low level + hand "
         "velocity; perception and domain randomization on). The privileged prior: heuristic demos (--from, or "
         "--prior-episodes generated into RUNDIR/prior) kept as --demo-share of every batch and, with "
         "--bc-weight, in a behaviour-cloning term; --no-prior trains without them. Every training rollout is "
         "an MCAP episode in RUNDIR/dataset (source high_level_training); held-out evaluations (first-attempt "
         "and overall success) go to RUNDIR/metrics.csv (hingelab report --runs RUNDIR); checkpoints with the "
         "replay buffer to RUNDIR/checkpoints (continue with --resume). --learner phase-clone fits the phase clone "
         "instead (the shipped policy's recipe): a network of the observation and its own memory of the "
         "demonstrator's phase, cloned from the prior's scripted demos, no SAC (RUNDIR/model.zip, one held-out "
         "evaluation in RUNDIR/metrics.csv). Every setting is a flag below and is saved in RUNDIR/config.json.",
         "runs/high_seed{SEED}")


def add_flat_parser(learners) -> None:
    from hingelab.learning.high_level_config import FlatTrainConfig

    _add(learners, "flat", FlatTrainConfig,
         "the flat baseline: one SAC policy on finger moves and hand velocity (ToolPickFlat-v0)",
         "Train the non-hierarchical baseline: SAC on hingelab/ToolPickFlat-v0, one policy acting on the 9 "
         "finger joint deltas and the hand velocity at once (no latent goal, no low level), same reward, "
         "success, episode end and randomization as ToolPick-v0. Rollouts, metrics and checkpoints as in "
         "hingelab train high (source flat_training).",
         "runs/flat_seed{SEED}", skip=FLAT_SKIPS)


def run_high(args: argparse.Namespace) -> int:
    from hingelab.learning.run_config import config_from_args, given_settings
    from hingelab.learning.run_folder import resumed_config
    from hingelab.learning.train_high import train_high
    from hingelab.paths import REPO_ROOT, refuse_to_replace_shipped

    if hasattr(args, "from_datasets"):  # train flat has no --from
        args.from_datasets = tuple(str(Path(p).resolve()) for p in args.from_datasets)
    if getattr(args, "low_level", "none") not in ("policy", "privileged", "none"):
        args.low_level = str(Path(args.low_level).resolve())
    config = config_from_args(args.config_class, args)
    out = args.out or REPO_ROOT / args.default_out.format(SEED=config.seed)
    refuse_to_replace_shipped(out, args.force)
    if args.resume:
        config = resumed_config(out, config, given_settings(args.config_class, args))
    s = train_high(config, out, resume=args.resume, progress=not args.no_progress, name=args.name)
    last, best = s["last_evaluation"], s["best"]
    prior = s["prior"]
    if prior:
        sources = ", ".join(f"{d['path']} ({d['source']}, {d['episodes']} episodes"
                            + (f", {len(d['skipped'])} left out" if d["skipped"] else "") + ")"
                            for d in prior["filled_from"])
        prior_text = (f" The privileged prior: {prior['transitions']} transitions of {prior['episodes']} episodes from "
                      f"{sources}" + (f", demo share {config.demo_share:g}, BC weight {config.demo_bc_weight:g}."
                                      if config.learner == "sac" else "."))
    else:
        prior_text = " No privileged prior."
    if "fit" in s:  # the phase clone
        fit = s["fit"]
        print(f"Cloned the high-level policy with phase memory in {s['wall_time_s'] / 60:.1f} min ({fit['updates']} "
              f"updates on {fit['demo_steps']} demo steps, phase accuracy {fit['phase_accuracy']:.3f}, on the "
              f"demonstrator's phase changes {fit['phase_change_accuracy']:.3f}).{prior_text} Evaluation on "
              f"{s['eval_episodes']} held-out episodes: success {float(last.get('success_rate', 0)):.2f}, at the first "
              f"attempt {float(last.get('first_attempt_success_rate', 0)):.2f}. Policy: {out}/model.zip "
              f"(hingelab eval high {out}/model.zip).")
        return 0
    what = "flat baseline" if config.kind == "flat" else "high-level policy"
    print(f"Trained the {what} to {s['env_steps']} env steps ({s['updates']} updates) in "
          f"{s['wall_time_s'] / 60:.1f} min.{prior_text} Last evaluation on {s['eval_episodes']} held-out "
          f"episodes: success {float(last.get('success_rate', 0)):.2f}, at the first attempt "
          f"{float(last.get('first_attempt_success_rate', 0)):.2f}. Best: success {best['success_rate']:.2f} at "
          f"{best.get('env_steps', '?')} steps ({out}/best_model.zip). Curves: hingelab report --runs {out}; "
          f"rollouts: {out}/dataset.")
    return 0
