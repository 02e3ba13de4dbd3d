"""``hingelab train high --learner dagger``: DAgger over the phase clone, in a run folder.

The run starts from a clone (``--base``: fitted on the run's privileged prior by the phase clone's recipe and
kept as ``RUNDIR/base.zip``, the shipped one, or a checkpoint) and then, each of ``--dagger-rounds`` rounds:
records ``--dagger-episodes`` rollouts of the current clone labelled by the scripted demonstrator
(``rollouts.ShadowedClone``) into ``RUNDIR/rounds/K``; fits every member again, going on from the last round's
nets, on the prior's demos and every round's labelled steps so far (``--dagger-updates``); saves the round's
clone as ``RUNDIR/rounds/round_K.zip`` and evaluates it into ``metrics.csv`` (``env_steps``: the rollout steps
so far). ``model.zip`` is the last round's clone, ``best_model.zip`` the best evaluated. ``--resume`` keeps the
rounds whose clone was saved, makes a cut-off round's rollouts again and goes on: the same clones, as every fit
depends only on its data and seeds. ``--jobs N``: the prior, the members' fits, the rounds' rollouts and the
evaluations in N worker processes (``hingelab.workers.job_pool``), with the same results.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.learners.dagger.config import DaggerConfig
from hingelab.learners.dagger.rollouts import generate_round
from hingelab.learners.phase_clone.fit import PhaseDemos, fit_phase_clone_members
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL, check_context, training_context
from hingelab.policies.phase_clone import PhaseClone
from hingelab.provenance import code_version
from hingelab.tasks import MAX_SPEED, Z_SCALE, observation_dim
from hingelab.training.high_level_demos import high_level_transitions
from hingelab.training.pick_run_parts import PickEvaluation, open_prior_run
from hingelab.training.run_folder import RunFolder
from hingelab.training.torch_process import one_torch_thread
from hingelab.workers.job_pool import job_pool

LABEL = "train high (DAgger)"
BASE_FILE, ROUNDS_DIR = "base.zip", "rounds"
# env arguments a clone must observe as it was trained, with ToolPick-v0's defaults
OBSERVED_FORM = {"observe_extent": False, "tool_position": "observed"}
_ROUND_SEED_STRIDE = 104_729  # a round's fit seeds, apart from the base fit's (run seed + member strides)


def round_file(run_dir: Path, round_index: int) -> Path:
    return Path(run_dir) / ROUNDS_DIR / f"round_{round_index}.zip"


def train_dagger(config: DaggerConfig, run_dir, resume: bool = False, progress: bool = True,
                 name: str | None = None) -> dict:
    """DAgger's rounds in a run folder (module doc); a summary dict."""
    with job_pool(config.jobs, one_torch_thread) as pool:
        return _train_dagger(config, run_dir, resume, progress, name, pool)


def _train_dagger(config: DaggerConfig, run_dir, resume: bool, progress: bool, name: str | None, pool) -> dict:
    started = time.perf_counter()
    folder, prior = open_prior_run(config, run_dir, "dagger", resume, progress, name, pool=pool)
    c = folder.config
    demos = PhaseDemos.from_transitions(prior.demos, where=", ".join(prior.info["datasets"]))
    clone, base_record = _base(c, folder, demos, progress, pool)
    if not resume:
        folder.record_run_fact("base", base_record)
    evaluation = PickEvaluation(c, pool=pool)

    done = 0  # rounds whose clone was saved: a resumed run goes on after the last
    while round_file(folder.path, done + 1).exists():
        done += 1
    labelled = [_round_demos(c, folder.path / ROUNDS_DIR / str(k)) for k in range(1, done + 1)]
    env_steps = sum(len(d) for d in labelled)
    if done:
        clone = PhaseClone.load(round_file(folder.path, done))
    folder.metrics.truncate_after(env_steps if done else -1)
    if not done:
        folder.metrics.append(_row(c, 0, 0, 0, evaluation(clone)))
    for k in range(done + 1, c.dagger_rounds + 1):
        if progress:
            print(f"{LABEL} {folder.name}: round {k} of {c.dagger_rounds}: {c.dagger_episodes} rollouts of the clone")
        generate_round(folder.path / ROUNDS_DIR / str(k), c, clone, k, name=f"{folder.name}-round{k}",
                       progress=progress, pool=pool)
        labelled.append(_round_demos(c, folder.path / ROUNDS_DIR / str(k)))
        env_steps += len(labelled[-1])
        data = PhaseDemos.concat([demos, *labelled])
        if progress:
            print(f"{LABEL} {folder.name}: round {k}: fitting on {len(data)} steps ({len(demos)} demo steps, "
                  f"{env_steps} labelled rollout steps)")
        nets, fit = fit_phase_clone_members(data, len(clone.nets), (), c.dagger_updates, c.clone_batch_size,
                                            c.dagger_learning_rate, c.seed + k * _ROUND_SEED_STRIDE,
                                            progress=progress, starts=clone.nets, pool=pool)
        clone = PhaseClone(nets)
        row = _row(c, k, env_steps, len(labelled[-1]), evaluation(clone))
        clone.hingelab_provenance = _provenance(c, prior, base_record, fit, row, k, env_steps)
        round_file(folder.path, k).parent.mkdir(parents=True, exist_ok=True)
        clone.save(round_file(folder.path, k))  # the round's checkpoint: a resume goes on after it
        folder.metrics.append(row)
        if progress:
            print(f"{LABEL} {folder.name}: round {k}: held-out success {row['success_rate']:.2f}, first attempt "
                  f"{row['first_attempt_success_rate']:.2f}")
    evaluation.close()

    final = PhaseClone.load(round_file(folder.path, c.dagger_rounds))
    final.save(folder.path / "model.zip")
    rows = [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in folder.metrics.rows()]
    best_row = rows[0]
    for row in rows[1:]:
        if PickEvaluation.is_better(row, best_row):
            best_row = row
    best_round = int(best_row["round"])
    best = PhaseClone.load(round_file(folder.path, best_round) if best_round else base_record["path"])
    best.save(folder.path / "best_model.zip")
    return {"run_dir": str(folder.path), "env_steps": env_steps, "rounds": c.dagger_rounds,
            "wall_time_s": time.perf_counter() - started, "last_evaluation": rows[-1],
            "best": {k: best_row[k] for k in PickEvaluation.initial_best()} | {"env_steps": best_row["env_steps"],
                                                                              "round": best_round},
            "prior": prior.info, "base": base_record, "eval_episodes": c.eval_episodes, "first_evaluation": rows[0]}


def _row(c, round_index: int, env_steps: int, round_steps: int, evaluated: dict) -> dict:
    return {"env_steps": env_steps, "seed": c.seed, "round": round_index, "round_steps": round_steps, **evaluated}


def _round_demos(c, root: Path) -> PhaseDemos:
    """A round's labelled steps (every dataset under ``root``)."""
    roots = sorted(p.parent for p in Path(root).glob("**/dataset.json"))
    if not roots:
        raise ConfigError(f"{root} holds no rollout datasets; resume the run again to make that round anew")
    extent = bool(c.env_kwargs.get("observe_extent", False))
    transitions = high_level_transitions(roots, c.reward, actions="recorded", observation_dim=observation_dim(extent))
    return PhaseDemos.from_transitions(transitions, where=str(root))


def _base(c, folder: RunFolder, demos: PhaseDemos, progress: bool, pool=None) -> tuple[PhaseClone, dict]:
    """The clone round 1 starts from, and its record (path, sha256, how it came about)."""
    if c.base == "fit":
        path = folder.path / BASE_FILE
        if not path.exists():  # a resumed run keeps the base it fitted
            if progress:
                print(f"{LABEL} {folder.name}: fitting the base clone on {len(demos)} demo steps "
                      f"({c.clone_updates} updates, {c.clone_members} member(s))")
            nets, fit = fit_phase_clone_members(demos, c.clone_members, tuple(c.net_arch), c.clone_updates,
                                                c.clone_batch_size, c.clone_learning_rate, c.seed, progress=progress,
                                                pool=pool)
            base = PhaseClone(nets)
            base.hingelab_provenance = {"env_id": c.env_id, "env_kwargs": c.env_arguments(), "learner": "phase-clone",
                                        "fit": fit, "fitted_by": "train high --learner dagger --base fit",
                                        "config": c.to_dict(), "seed": c.seed, **code_version(),
                                        **training_context(c.low_level)}
            base.save(path)
    else:
        path = SHIPPED_HIGH_LEVEL if c.base == "shipped" else Path(c.base)
        if not path.is_file():
            raise ConfigError(f"--base {c.base}: no file at {path}; give a phase-clone checkpoint, shipped or fit")
    base = PhaseClone.load(path)
    if base.observation_dim != demos.observations.shape[1]:
        raise ConfigError(f"the base {path} takes {base.observation_dim}-D observations, the run's demos are "
                          f"{demos.observations.shape[1]}-D: set observe_extent in --env-kwargs as the base was "
                          "trained")
    check_context(base, path, c.low_level)
    trained = (base.hingelab_provenance or {}).get("env_kwargs")
    run = c.env_arguments()
    for key, default in OBSERVED_FORM.items() if trained is not None else ():  # (older clones: not recorded)
        if trained.get(key, default) != run.get(key, default):
            raise ConfigError(f"the base {path} was trained with {key}={trained.get(key, default)!r}, the run has "
                              f"{run.get(key, default)!r}: give --env-kwargs with {key} as the base's")
    record = {"path": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest(), "nets": len(base.nets),
              "how": c.base if c.base in ("fit", "shipped") else "checkpoint"}
    return base, record


def _provenance(c, prior, base_record: dict, fit: dict, row: dict, round_index: int, env_steps: int) -> dict:
    return {"env_id": c.env_id, "env_kwargs": c.env_arguments(),
            "action_scale": {"z_goal": Z_SCALE, "hand_velocity_m_s": MAX_SPEED}, "config": c.to_dict(), "seed": c.seed,
            "learner": "dagger", **code_version(), **training_context(c.low_level),
            "prior": {**prior.info, "demo_actions": prior.modes, "demo_lookahead": c.demo_lookahead},
            "dagger": {"round": round_index, "rounds": c.dagger_rounds, "labelled_steps": env_steps,
                       "base": base_record},
            "fit": fit, "evaluation": row}


__all__ = ["train_dagger", "round_file", "LABEL"]
