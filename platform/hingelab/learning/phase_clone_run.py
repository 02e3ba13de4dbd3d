"""``hingelab train high --learner phase-clone``: the phase clone (``phase_clone``) fitted in a run folder.

The run shares ``train high``'s folder, prior and evaluation (``train_high.HighLevelRun``): the
scripted demos generated into ``RUNDIR/prior`` (their steps record the demonstrator's phases) or
given with ``--from``; ``--clone-updates`` updates of the clone on them; one held-out evaluation
(``--eval-episodes`` of ``eval high --seed 77``'s episodes) into ``metrics.csv``; ``model.zip``
(and ``best_model.zip``, the same policy) recording the env arguments, the low level's sha256,
the encoder's fingerprint, the prior and the fit. There is no SAC and no env step of the run's
own, so the run's dataset holds no training rollouts.

``--resume`` continues where the run stopped: a prior whose every dataset was written is kept
(a cut-off generation is made again); the clone is fitted again from the start (a few minutes),
which gives the same weights, as the fit depends only on the demos and the seed.
"""

from __future__ import annotations

import time

from hingelab.learning.fast_sac import configure_torch
from hingelab.learning.train_high import EVAL_SEED, HighLevelRun


class PhaseCloneRun(HighLevelRun):
    label = "train high (phase clone)"

    def setup(self):
        configure_torch(self.config.torch_threads)
        self.started = time.perf_counter()
        if not self.resume:
            self.prepare_new_run()
            self.folder.write_run_files()
        self.prepare_data()
        self.make_evaluator()
        return self

    def train(self) -> dict:
        from hingelab.learning.phase_clone import PhaseClone, PhaseDemos, fit_phase_clone

        c = self.config
        demos = PhaseDemos.from_transitions(self.demos, where=", ".join(self.demo_info["datasets"]))
        if self.progress:
            print(f"{self.label} {self.name}: cloning {len(demos)} demo steps of {self.demo_info['episodes']} "
                  f"episodes ({c.clone_updates} updates, net {' x '.join(str(n) for n in c.net_arch)})")
        net, fit = fit_phase_clone(demos, tuple(c.net_arch), c.clone_updates, c.clone_batch_size,
                                   c.clone_learning_rate, c.seed, progress=self.progress)
        self.model = PhaseClone(net)
        self.model.hingelab_provenance = self.provenance({"fit": fit})
        self.metrics.truncate_after(-1)  # a resumed run evaluates its clone again
        evaluation = {"env_steps": 0, "seed": c.seed, "updates": c.clone_updates, **self.evaluate_policy()}
        self.metrics.append(evaluation)
        self.model.hingelab_provenance = self.provenance({"fit": fit, "evaluation": evaluation})
        for name in ("best_model.zip", "model.zip"):  # one policy: the clone is not trained further
            self.model.save(self.run_dir / name)
        self.close_evaluator()
        self.best = {k: evaluation[k] for k in self.initial_best()} | {"env_steps": 0}
        return {"run_dir": str(self.run_dir), "env_steps": 0, "updates": c.clone_updates,
                "wall_time_s": time.perf_counter() - self.started, "last_evaluation": evaluation, "best": self.best,
                "fit": fit, "prefill": None, **self.summary_extra()}

    def summary_extra(self) -> dict:
        return {**super().summary_extra(), "eval_seed": EVAL_SEED}


__all__ = ["PhaseCloneRun"]
