"""SAC (stable-baselines3, with the faster update of ``fast_sac`` and the demonstration variant of
``demo_sac``) for the three levels: ``train low`` (ToolShape-v0), ``train high`` (ToolPick-v0 over the
frozen low level, from the privileged prior) and ``train flat`` (ToolPickFlat-v0). The training core is
``run.SACRun``; its callbacks are in ``callbacks``."""

from __future__ import annotations

from hingelab.learners.registry import register_learner
from hingelab.learners.sac.high_level_config import FlatTrainConfig, HighLevelTrainConfig
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig


def _prior_text(result: dict, config) -> str:
    prior = result.get("prior")
    if not prior:
        return " No privileged prior."
    sources = ", ".join(f"{d['path']} ({d['source']}, {d['episodes']} episodes"
                        + (f", {len(d['skipped'])} left out" if d["skipped"] else "") + ")"
                        for d in prior["filled_from"])
    return (f" The privileged prior: {prior['transitions']} transitions of {prior['episodes']} episodes from {sources}"
            f", demo share {config.demo_share:g}, BC weight {config.demo_bc_weight:g}.")


def _pick_summary(what: str, result: dict, config, run_dir) -> str:
    last, best = result["last_evaluation"], result["best"]
    prior = _prior_text(result, config) if isinstance(config, HighLevelTrainConfig) else " No privileged prior."
    return (f"Trained the {what} to {result['env_steps']} env steps ({result['updates']} updates) in "
            f"{result['wall_time_s'] / 60:.1f} min.{prior} Last evaluation on {result['eval_episodes']} held-out "
            f"episodes: success {float(last.get('success_rate', 0)):.2f}, at the first attempt "
            f"{float(last.get('first_attempt_success_rate', 0)):.2f}. Best: success {best['success_rate']:.2f} at "
            f"{best.get('env_steps', '?')} steps ({run_dir}/best_model.zip). Curves: hingelab report --runs "
            f"{run_dir}; rollouts: {run_dir}/dataset.")


@register_learner
class SACLowLevel:
    name, level = "sac", "low"
    config_class = LowLevelTrainConfig
    default_out = "runs/low_seed{SEED}"
    help = "the low-level policy: SAC shaping the tweezer to latent goals (ToolShape-v0)"
    description = ("Train the goal-conditioned low-level SAC policy on hingelab/ToolShape-v0. Every training "
                   "rollout is written as MCAP episodes into RUNDIR/dataset; evaluations on fixed held-out "
                   "goals go to RUNDIR/metrics.csv (hingelab report RUNDIR draws the curves); checkpoints "
                   "with the replay buffer go to RUNDIR/checkpoints (continue with --resume). All settings "
                   "are saved in RUNDIR/config.json; every one of them is a flag below.")

    @staticmethod
    def default_out_for(config) -> str:
        return f"runs/low_seed{config.seed}{'' if config.use_effort else '_no_effort'}"

    @staticmethod
    def train(config, run_dir, resume=False, progress=True, name=None) -> dict:
        from hingelab.learners.sac.low_level import train_low  # the run's modules load when a run starts

        return train_low(config, run_dir, resume=resume, progress=progress, name=name)

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        last, best = result["last_evaluation"], result["best"]
        prefill = ""
        if result["prefill"]:
            pf = result["prefill"]
            prefill = (f" The replay buffer was pre-filled with {pf['transitions']} transitions from "
                       f"{pf['episodes']} episodes at {pf['transitions_per_s']:.0f} transitions/s.")
        return (f"Trained the low-level policy to {result['env_steps']} env steps ({result['updates']} updates) in "
                f"{result['wall_time_s'] / 60:.1f} min.{prefill} Last evaluation: success "
                f"{float(last.get('success_rate', 0)):.2f} on {result['eval_goals']} held-out reachable goals, final "
                f"latent distance {float(last.get('final_latent_distance', 0)):.3f}, max tool drift "
                f"{float(last.get('tool_drift_mm_max', 0)):.1f} mm. Best: success {best['success_rate']:.2f} at "
                f"{best.get('env_steps', '?')} steps ({run_dir}/best_model.zip). Curves: hingelab report {run_dir}; "
                f"rollouts: {run_dir}/dataset.")


@register_learner
class SACHighLevel:
    name, level = "sac", "high"
    config_class = HighLevelTrainConfig
    default_out = "runs/high_seed{SEED}"
    help = "the high-level policy: SAC picking with the tweezer over the frozen low level (ToolPick-v0)"
    description = ("Train the high-level SAC policy on hingelab/ToolPick-v0 (latent goal for the frozen low level "
                   "+ hand velocity; perception and domain randomization on). The privileged prior: demos (--from, "
                   "or --prior-episodes generated into RUNDIR/prior) kept as --demo-share of every batch and, with "
                   "--bc-weight, in a behaviour-cloning term; --no-prior trains without them. Every training rollout "
                   "is an MCAP episode in RUNDIR/dataset (source high_level_training); held-out evaluations "
                   "(first-attempt and overall success) go to RUNDIR/metrics.csv (hingelab report --runs RUNDIR); "
                   "checkpoints with the replay buffer to RUNDIR/checkpoints (continue with --resume). Every setting "
                   "is a flag below and is saved in RUNDIR/config.json.")

    @staticmethod
    def train(config, run_dir, resume=False, progress=True, name=None) -> dict:
        from hingelab.learners.sac.high_level import train_high  # the run's modules load when a run starts

        return train_high(config, run_dir, resume=resume, progress=progress, name=name)

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        return _pick_summary("high-level policy", result, config, run_dir)


@register_learner
class SACFlat(SACHighLevel):  # the same run (train_high picks FlatRun by the config)
    name, level = "sac", "flat"
    config_class = FlatTrainConfig
    default_out = "runs/flat_seed{SEED}"
    help = "the flat baseline: one SAC policy on finger moves and hand velocity (ToolPickFlat-v0)"
    description = ("Train the non-hierarchical baseline: SAC on hingelab/ToolPickFlat-v0, one policy acting on the 9 "
                   "finger joint deltas and the hand velocity at once (no latent goal, no low level), same reward, "
                   "success, episode end and randomization as ToolPick-v0. Rollouts, metrics and checkpoints as in "
                   "hingelab train high (source flat_training).")

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        return _pick_summary("flat baseline", result, config, run_dir)
