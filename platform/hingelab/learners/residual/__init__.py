"""Residual SAC over a frozen phase clone (``hingelab train high --learner residual-sac``): reinforcement
learning that starts as its demonstrator's clone and may only correct it by a bounded amount. The policy and
its file format are ``hingelab.policies.residual``; here are the settings (``config``), the networks
(``networks``), the update (``algorithm``), the envs as the residual sees them (``vec_env``) and the run
(``run``)."""

from __future__ import annotations

from hingelab.learners.registry import register_learner
from hingelab.learners.residual.config import ResidualSACConfig


@register_learner
class ResidualSACLearner:
    name, level = "residual-sac", "high"
    config_class = ResidualSACConfig
    default_out = "runs/residual_seed{SEED}"
    help = "SAC of a bounded residual over a frozen phase clone: RL that starts as the clone"
    description = ("Fine-tune a high-level policy with reinforcement learning on hingelab/ToolPick-v0 without "
                   "losing it: SAC learns a correction of at most --residual-scale per action dimension over a "
                   "frozen phase clone (--base: the shipped one, a checkpoint, or one fitted first on the run's "
                   "privileged prior), which it acts as at step 0. The policy acts from the first step; the "
                   "critics (an ensemble with LayerNorm) learn alone until --actor-start; exploration noise is "
                   "capped per action dimension (--exploration-bound); the prior's demos stay in every batch "
                   "(--demo-share). Rollouts, evaluations, checkpoints and --resume as in train high; the policy "
                   "is RUNDIR/model.zip (hingelab eval high RUNDIR/model.zip). Every setting is a flag below and "
                   "is saved in RUNDIR/config.json.")

    @staticmethod
    def train(config, run_dir, resume=False, progress=True, name=None) -> dict:
        from hingelab.learners.residual.run import train_residual  # the run's modules load when a run starts

        return train_residual(config, run_dir, resume=resume, progress=progress, name=name)

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        last, best = result["last_evaluation"], result["best"]
        return (f"Trained the residual over {result['base']} to {result['env_steps']} env steps ({result['updates']} "
                f"updates) in {result['wall_time_s'] / 60:.1f} min. Last evaluation on {result['eval_episodes']} "
                f"held-out episodes: success {float(last.get('success_rate', 0)):.2f}, at the first attempt "
                f"{float(last.get('first_attempt_success_rate', 0)):.2f}. Best: success {best['success_rate']:.2f} "
                f"at {best.get('env_steps', '?')} steps ({run_dir}/best_model.zip). Curves: hingelab report --runs "
                f"{run_dir}; rollouts: {run_dir}/dataset.")
