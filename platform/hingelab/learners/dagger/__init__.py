"""DAgger over the phase clone: the clone's own rollouts labelled by the scripted demonstrator, fitted again
round by round (``hingelab train high --learner dagger``; Ross et al. 2011). Its settings (``config``), its
rollouts (``rollouts``) and its run (``run``); the policy it writes is a phase clone
(``hingelab.policies.phase_clone``)."""

from __future__ import annotations

from hingelab.learners.dagger.config import DaggerConfig
from hingelab.learners.registry import register_learner


@register_learner
class DaggerLearner:
    name, level = "dagger", "high"
    config_class = DaggerConfig
    default_out = "runs/dagger_seed{SEED}"
    help = "DAgger over the phase clone: its own rollouts labelled by the scripted demonstrator (no SAC)"
    description = ("DAgger on hingelab/ToolPick-v0 over the phase clone: start from a clone (--base: fitted on the "
                   "run's privileged prior, the shipped one, or a checkpoint), then, each of --dagger-rounds rounds, "
                   "record --dagger-episodes rollouts of the clone in which the scripted demonstrator, run on the "
                   "same states, labels every step with its action and next phase (RUNDIR/rounds/K), and fit the "
                   "clone again on the prior's demos and every labelled step so far. Imitation error is what it "
                   "removes: the clone learns what the demonstrator would do in the states the clone itself reaches. "
                   "RUNDIR/model.zip is the last round's clone (best_model.zip the best evaluated); metrics.csv has "
                   "one held-out evaluation per round. --jobs N shares the prior's episodes, the members' fits, "
                   "the rounds' rollouts and the evaluations among N worker processes: the same prior, labels, "
                   "weights and metrics as one, sooner. Every setting is a flag below and is saved in "
                   "RUNDIR/config.json.")

    @staticmethod
    def train(config, run_dir, resume=False, progress=True, name=None) -> dict:
        from hingelab.learners.dagger.run import train_dagger  # loads torch when a run starts

        return train_dagger(config, run_dir, resume=resume, progress=progress, name=name)

    @staticmethod
    def summary(result: dict, config, run_dir) -> str:
        first, last, best = result["first_evaluation"], result["last_evaluation"], result["best"]
        return (f"DAgger over the phase clone in {result['wall_time_s'] / 60:.1f} min: {result['rounds']} rounds, "
                f"{result['env_steps']} labelled rollout steps. Held-out evaluation ({result['eval_episodes']} "
                f"episodes): the base {first['success_rate']:.2f} (first attempt "
                f"{first['first_attempt_success_rate']:.2f}), the last round {last['success_rate']:.2f} "
                f"({last['first_attempt_success_rate']:.2f}); the best was round {best['round']}. "
                f"Policy: {run_dir}/model.zip (hingelab eval high {run_dir}/model.zip).")
