"""``hingelab train high --learner phase-clone``: the phase clone (``hingelab.policies.phase_clone``)
fitted in a run folder.

The run has ``train high``'s folder, prior and evaluation: the scripted demos generated into
``RUNDIR/prior`` (their steps record the demonstrator's phases) or given with ``--from``;
``--clone-updates`` updates of each of ``--clone-members`` nets (an ensemble) on them; one held-out
evaluation into ``metrics.csv``; ``model.zip`` (and ``best_model.zip``, the same policy) recording the
env arguments, the low level's sha256, the encoder's fingerprint, the prior and the fit. No env step of
the run's own, so the run's dataset holds no training rollouts. ``--resume`` keeps a prior whose every
dataset was written (a cut-off generation is made again) and fits the clone again from the start: the
same weights, as the fit depends only on the demos and the seed. ``--jobs N``: the prior, the members' fits and
the evaluation in N worker processes (``hingelab.workers.job_pool``), with the same results.
"""

from __future__ import annotations

import time

from hingelab.learners.phase_clone.config import PhaseCloneConfig
from hingelab.learners.phase_clone.fit import PhaseDemos, fit_phase_clone_members
from hingelab.policies.high_level import training_context
from hingelab.policies.phase_clone import PhaseClone
from hingelab.provenance import code_version
from hingelab.tasks import MAX_SPEED, Z_SCALE
from hingelab.training.pick_run_parts import PickEvaluation, open_prior_run
from hingelab.training.torch_process import one_torch_thread
from hingelab.workers.job_pool import job_pool

LABEL = "train high (phase clone)"


def train_phase_clone(config: PhaseCloneConfig, run_dir, resume: bool = False, progress: bool = True,
                      name: str | None = None) -> dict:
    """Fit (or fit again, on ``resume``) the phase clone of a run folder; a summary dict."""
    with job_pool(config.jobs, one_torch_thread) as pool:
        return _train_phase_clone(config, run_dir, resume, progress, name, pool)


def _train_phase_clone(config: PhaseCloneConfig, run_dir, resume: bool, progress: bool, name: str | None,
                       pool) -> dict:
    started = time.perf_counter()
    folder, prior = open_prior_run(config, run_dir, "phase-clone", resume, progress, name, pool=pool)
    c = folder.config
    evaluation = PickEvaluation(c, pool=pool)

    demos = PhaseDemos.from_transitions(prior.demos, where=", ".join(prior.info["datasets"]))
    if progress:
        print(f"{LABEL} {folder.name}: cloning {len(demos)} demo steps of {prior.info['episodes']} episodes "
              f"({c.clone_updates} updates, net {' x '.join(str(n) for n in c.net_arch)}"
              f"{f', {c.clone_members} members' if c.clone_members > 1 else ''})")
    nets, fit = fit_phase_clone_members(demos, c.clone_members, tuple(c.net_arch), c.clone_updates,
                                        c.clone_batch_size, c.clone_learning_rate, c.seed, progress=progress,
                                        pool=pool)
    model = PhaseClone(nets)
    folder.metrics.truncate_after(-1)  # a resumed run evaluates its clone again
    row = {"env_steps": 0, "seed": c.seed, "updates": c.clone_updates, **evaluation(model)}
    folder.metrics.append(row)
    prior_record = {**prior.info, "demo_actions": prior.modes, "demo_lookahead": c.demo_lookahead}
    model.hingelab_provenance = {
        "env_id": c.env_id, "env_kwargs": c.env_arguments(),
        "action_scale": {"z_goal": Z_SCALE, "hand_velocity_m_s": MAX_SPEED}, "config": c.to_dict(), "seed": c.seed,
        "learner": "phase-clone", **code_version(), **training_context(c.low_level), "prior": prior_record,
        "fit": fit, "evaluation": row}
    for file in ("best_model.zip", "model.zip"):  # one policy: the clone is not trained further
        model.save(folder.path / file)
    evaluation.close()
    best = {k: row[k] for k in PickEvaluation.initial_best()} | {"env_steps": 0}
    return {"run_dir": str(folder.path), "env_steps": 0, "updates": c.clone_updates,
            "wall_time_s": time.perf_counter() - started, "last_evaluation": row, "best": best, "fit": fit,
            "prefill": None, "prior": prior.info, "eval_episodes": c.eval_episodes}


__all__ = ["train_phase_clone", "LABEL"]
