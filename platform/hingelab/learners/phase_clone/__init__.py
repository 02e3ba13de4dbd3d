"""The phase clone: behaviour cloning of the scripted demonstrator with its phase as the policy's memory
(``hingelab train high --learner phase-clone``). The policy and its file format are
``hingelab.policies.phase_clone``; here are its settings (``config``), its fit (``fit``) and its run (``run``)."""

from __future__ import annotations

from hingelab.learners.phase_clone.config import PhaseCloneConfig
from hingelab.learners.registry import register_learner


@register_learner
class PhaseCloneLearner:
    name, level = "phase-clone", "high"
    config_class = PhaseCloneConfig
    default_out = "runs/high_seed{SEED}"
    help = "the phase clone: the scripted demonstrator cloned with its phase as memory (no SAC)"
    description = ("Fit the phase clone on hingelab/ToolPick-v0 (the shipped high-level policy's recipe): a network "
                   "of the observation and its own memory of the demonstrator's phase and the steps spent in it, "
                   "which it predicts each step, cloned from scripted demos that record their phases (generated into "
                   "RUNDIR/prior, or --from). No env steps of its own: RUNDIR/model.zip and one held-out evaluation "
                   "in RUNDIR/metrics.csv. --jobs N shares the prior's episodes, the members' fits and the "
                   "evaluation among N worker processes: the same prior, weights and metrics as one, sooner. Every "
                   "setting is a flag below and is saved in RUNDIR/config.json.")

    @staticmethod
    def train(config, run_dir, resume=False, progress=True, name=None) -> dict:
        from hingelab.learners.phase_clone.run import train_phase_clone  # loads torch when a run starts

        return train_phase_clone(config, run_dir, resume=resume, progress=progress, name=name)

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        fit, last, prior = result["fit"], result["last_evaluation"], result["prior"]
        sources = ", ".join(f"{d['path']} ({d['source']}, {d['episodes']} episodes"
                            + (f", {len(d['skipped'])} left out" if d["skipped"] else "") + ")"
                            for d in prior["filled_from"])
        return (f"Cloned the high-level policy with phase memory in {result['wall_time_s'] / 60:.1f} min "
                f"({fit['updates']} updates on {fit['demo_steps']} demo steps, phase accuracy "
                f"{fit['phase_accuracy']:.3f}, on the demonstrator's phase changes {fit['phase_change_accuracy']:.3f})."
                f" The privileged prior: {prior['transitions']} transitions of {prior['episodes']} episodes from "
                f"{sources}. Evaluation on {result['eval_episodes']} held-out episodes: success "
                f"{float(last.get('success_rate', 0)):.2f}, at the first attempt "
                f"{float(last.get('first_attempt_success_rate', 0)):.2f}. Policy: {run_dir}/model.zip "
                f"(hingelab eval high {run_dir}/model.zip).")
