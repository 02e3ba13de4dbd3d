"""The evaluation runner: a policy or a baseline for N episodes into a dataset folder, with its tables.

``evaluate_low`` (ToolShape-v0, sampled reachable goals) and ``evaluate_high`` (ToolPick-v0, one object)
do what ``hingelab eval low`` and ``hingelab eval high`` do, and the demo calls them too:

1. check the policy (a checkpoint path, loaded by ``hingelab.policies``, or a baseline's name) and the
   task before any file is written;
2. start the dataset folder ``out`` (its card records the policy, the env and the seeds), or continue a
   stopped evaluation of it (``resume``: ``rollouts.journal``);
3. run the episodes here, or as Ray tasks (``ray``: ``"local"`` or a cluster address), each reset from its
   own seed; a full disk stops with one line that says how to resume;
4. write ``episodes.csv``, the success table (``regions.csv`` / ``table.csv``) and ``report.md``.

It returns an ``Evaluation``: the episode rows, the table, the one-paragraph summary. In Python::

    from hingelab.rollouts.evaluation import evaluate_high
    result = evaluate_high("assets/checkpoints/high_level.zip", out="datasets/eval_cube", object="cube",
                           episodes=20, seed=0)
    print(result.summary)
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from hingelab.analysis.documents import markdown_table
from hingelab.disk_full import disk_full_error, is_disk_full
from hingelab.envs.low_level import PolicyLowLevel
from hingelab.envs.tool_shape import SETTLE_STEPS
from hingelab.episodes import create_dataset
from hingelab.errors import ConfigError
from hingelab.perception.object_perception import check_object_perception_with
from hingelab.policies import ModelPolicy, load_policy
from hingelab.policies.high_level import (
    SHIPPED_HIGH_LEVEL,
    check_context,
    observes_extent,
    resolve_checkpoint,
    trained_tool_position,
)
from hingelab.policies.loading import baseline_names
from hingelab.policies.low_level import SHIPPED_LOW_LEVEL
from hingelab.rollouts import high_level as H
from hingelab.rollouts import low_level as L
from hingelab.rollouts.journal import EpisodeJournal, command_line, prepare_resume
from hingelab.rollouts.on_ray import evaluate_high_on_ray, evaluate_low_on_ray


@dataclass
class Evaluation:
    out: Path
    label: str
    episodes: pd.DataFrame
    table: pd.DataFrame
    summary: str
    details: dict = field(default_factory=dict)  # the env's facts the summary quotes (thresholds, ranges)


@contextmanager
def stop_cleanly_on_a_full_disk(out: Path, journal: EpisodeJournal, episodes: int, command: list[str] | None):
    """A full disk during an evaluation: one line (folder, free space, episodes kept), resumable."""
    try:
        yield
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        raise disk_full_error(out, len(journal.rows), episodes, command_line(command)) from exc


def _check_choice(policy, baseline: str | None, level: str, episodes: int) -> None:
    if baseline and policy is not None:
        raise ConfigError("give a checkpoint or --baseline, not both")
    if baseline and baseline not in baseline_names(level):
        raise ConfigError(f"unknown baseline {baseline!r} for eval {level}; choose one of "
                          f"{', '.join(baseline_names(level))}")
    if episodes < 1:
        raise ConfigError("--episodes must be at least 1")


def _start(out: Path, config: dict, seed: int, resume: bool, name: str, source: str, description: str):
    journal = prepare_resume(out, {**config, "seed": seed}, resume)
    if not resume:
        create_dataset(out, name=name, source=source, config={**config, "seed": seed}, seed=seed,
                       description=description)
    return journal


# ------------------------------------------------------------------ the low level
def evaluate_low(policy=None, *, out, baseline: str | None = None, episodes: int = 10, seed: int = 0,
                 randomize: bool = True, perception: str = "synthesized", resume: bool = False,
                 ray: str | None = None, progress: bool = True, command: list[str] | None = None,
                 name: str | None = None, description: str | None = None) -> Evaluation:
    """``episodes`` sampled reachable goals of ToolShape-v0 for a low-level checkpoint (default: the shipped
    one) or a baseline (``hold-still``, ``synergy``), recorded into ``out``."""
    out = Path(out)
    _check_choice(policy, baseline, "low", episodes)
    checkpoint = None if baseline else Path(policy if policy is not None else SHIPPED_LOW_LEVEL)
    model = None if baseline else PolicyLowLevel(checkpoint).model
    label = baseline or str(checkpoint)
    provenance = getattr(model, "hingelab_provenance", {}) or {}
    # the env the checkpoint was trained on (its record), on held-out goals: not its training goal band
    env_args = {**(L.evaluation_env_arguments(model) if model is not None else {}), "randomize": randomize}
    if perception != "synthesized":  # recorded only when it differs: older evaluations resume unchanged
        env_args["perception"] = perception
    config = {"checkpoint": label, "episodes": episodes, "env": env_args,
              "checkpoint_git_commit": provenance.get("git_commit", "unknown")}
    if name is None:  # a run's model.zip and best_model.zip: the run folder names the dataset
        name = f"eval-{baseline}" if baseline else f"eval-{checkpoint.parent.name}-{checkpoint.stem}"
        if perception != "synthesized":  # a report of both sets of one policy tells them apart by name
            name += f"-{perception}"
    journal = _start(out, config, seed, resume, name, "low_level_evaluation",
                     description or "hingelab eval low: a low-level policy toward reachable goals")
    env = L.make_eval_env(env_args, record_dir=None if ray else out)  # --ray: the tasks record
    unwrapped = env.unwrapped
    acting = load_policy(baseline, env=env) if baseline else model
    try:
        with stop_cleanly_on_a_full_disk(out, journal, episodes, command):
            if ray:
                goals = L.sampled_goals(unwrapped.calibration, unwrapped.reachable_range, episodes, seed)
                rows = evaluate_low_on_ray(goals, env_args, out, checkpoint, baseline, journal, ray, progress=progress)
            else:
                rows = L.evaluate_sampled_goals(acting, env, episodes, seed, progress=progress, journal=journal)
    finally:
        env.close()
    table = L.region_table(rows)
    rows.to_csv(out / "episodes.csv", index=False)
    journal.finish()
    table.to_csv(out / "regions.csv", index=False)
    details = {"success_threshold": unwrapped.success_threshold, "reachable_range": unwrapped.reachable_range,
               "success_verdict": unwrapped.success_verdict}
    overall = table[table["goal_region"] == "all"].iloc[0]
    summary = (f"Evaluated {label} on {episodes} reachable goals: success (settled over the last {SETTLE_STEPS} "
               f"steps, the episodes' recorded verdict) {int(overall['successes'])}/{episodes} = "
               f"{overall['success_rate']:.2f} [{overall['ci_low']:.2f}, {overall['ci_high']:.2f}] (with the tool "
               f"drifting under 1 cm {overall['success_and_drift_under_1cm']:.2f}); secondary, the last step alone "
               f"{overall['last_step_success_rate']:.2f}; median tip-gap error "
               f"{overall['tip_gap_error_mm_median']:.1f} mm. Dataset, episodes.csv, regions.csv, report.md in {out}.")
    (out / "report.md").write_text(
        f"# Low-level evaluation of {label}\n\n{episodes} episodes, seed {seed}, "
        f"env {json.dumps(env_args)}; success threshold {unwrapped.success_threshold:.4f} (latent distance "
        f"of 2 mm tip gap); regions are thirds of the reachable opening range "
        f"{unwrapped.reachable_range[0]:.3f}..{unwrapped.reachable_range[1]:.3f} rad. `success` (the env's "
        f"verdict, `{unwrapped.success_verdict}`, recorded as each episode's success): z_bar averaged over the last "
        f"{SETTLE_STEPS} steps (0.5 s) within the threshold; `last_step_` (secondary, not counted as success): "
        f"z_bar of the last step alone within it; `tip_gap_error_mm`: the privileged tip gap over the last "
        f"{SETTLE_STEPS} steps against the gap of the goal's calibrated opening.\n\n"
        + markdown_table(table.round(3)) + "\n")
    return Evaluation(out, label, rows, table, summary, details)


# ------------------------------------------------------------------ the high level
def evaluate_high(policy=None, *, out, baseline: str | None = None, object: str = "sphere", size: float = 0.02,
                  episodes: int = 10, seed: int = 0, low_level: str | None = None, perception: str = "synthesized",
                  object_perception: str = "truth", resume: bool = False, ray: str | None = None, progress: bool = True,
                  object_noise: str = "gaussian", object_noise_model: str | None = None,
                  tool_position: str | None = None, command: list[str] | None = None, name: str | None = None,
                  description: str | None = None) -> Evaluation:
    """``episodes`` episodes of ToolPick-v0 with one object for a high-level checkpoint (default: the shipped
    one) or a baseline (``heuristic``, ``scripted``, ...), over ``low_level`` (default: the one the checkpoint
    learned over; the privileged one for the heuristic), recorded into ``out``; ``object_perception``: the
    object's true centre with 2 mm noise (``truth``) or a camera object estimator (needs ``perception="camera"``);
    ``object_noise``: ``"fitted:NAME"``, the camera's error drawn from the fitted model at ``object_noise_model``;
    ``tool_position``: ToolPick-v0's "observed" or "anchored" tool position (default: what the checkpoint was
    trained on; "observed" for a baseline)."""
    out = Path(out)
    _check_choice(policy, baseline, "high", episodes)
    if policy is None and not baseline:
        if not SHIPPED_HIGH_LEVEL.exists():
            raise ConfigError(f"there is no shipped high-level policy ({SHIPPED_HIGH_LEVEL}) yet: give a checkpoint "
                              "trained on ToolPick-v0 (hingelab train high), or --baseline heuristic|scripted|random")
        policy = SHIPPED_HIGH_LEVEL
    if baseline:
        acting, label, extent = load_policy(baseline), baseline, False
        # the heuristic bypasses the low level: privileged, as in hingelab generate heuristic
        low_level = "privileged" if baseline == "heuristic" else (low_level or "policy")
    else:
        model = load_policy(resolve_checkpoint(policy), level="high")
        recorded = getattr(model, "hingelab_provenance", None) or {}
        low_level = low_level or recorded.get("low_level", "policy")
        check_context(model, policy, low_level)
        acting, label, extent = ModelPolicy(model), str(policy), observes_extent(model)
        tool_position = tool_position or trained_tool_position(model)
    tool_position = tool_position or "observed"
    # a bad object or low level: an error before files
    check_object_perception_with(object_perception, perception)  # before building an env
    # the env's settings that differ from its defaults: recorded only then, so older evaluations resume unchanged
    changed = {} if object_noise == "gaussian" and object_noise_model is None else {
        "object_noise": object_noise, "object_noise_model": object_noise_model}
    if tool_position != "observed":
        changed["tool_position"] = tool_position
    H.make_eval_env(object, size, low_level, observe_extent=extent, perception=perception,
                    object_perception=object_perception, **changed).close()
    config = {"policy": label, "object": object, "size": size, "episodes": episodes, "low_level": low_level,
              "observe_extent": extent, "seeds": f"{H.SEED_BASE} + seed * {H.SEED_STRIDE} + episode"}
    if perception != "synthesized":  # recorded only when it differs: older evaluations resume unchanged
        config["perception"] = perception
    if object_perception != "truth":  # the same: recorded only when it differs
        config["object_perception"] = object_perception
    config.update(changed)
    if name is None:
        name = f"eval-high-{baseline or Path(policy).stem}" + (f"-{perception}" if perception != "synthesized" else "")
        name += f"-object-{object_perception}" if object_perception != "truth" else ""
        name += f"-object-noise-{object_noise.replace(':', '-')}" if "object_noise" in changed else ""
        name += f"-tool-{tool_position}" if tool_position != "observed" else ""
    journal = _start(out, config, seed, resume, name, "high_level_evaluation",
                     description or f"hingelab eval high: {label} on ToolPick-v0, {object} {size * 100:g} cm")
    env_options = {"object": object, "size": size, "low_level": low_level, "observe_extent": extent,
                   "extra_metadata": {"policy": label, "low_level": low_level, "perception": perception,
                                      **({"tool_position": tool_position} if tool_position != "observed" else {})},
                   "perception": perception,
                   **({"object_perception": object_perception} if object_perception != "truth" else {}), **changed}
    with stop_cleanly_on_a_full_disk(out, journal, episodes, command):
        if ray:
            rows = evaluate_high_on_ray(episodes, seed, env_options, out, None if baseline else policy, baseline,
                                        journal, ray, progress=progress)
        else:
            env = H.make_eval_env(record_dir=out, **env_options)
            try:
                rows = H.evaluate(acting, env, episodes, seed, progress=progress, label=f"eval high {label}",
                                  journal=journal)
            finally:
                env.close()
    table = H.success_table(rows, object, size)
    noted = f" (object noise {object_noise})" if "object_noise" in changed else ""
    noted += f" ({tool_position} tool position)" if tool_position != "observed" else ""
    rows.to_csv(out / "episodes.csv", index=False)
    journal.finish()
    table.to_csv(out / "table.csv", index=False)
    row = table.iloc[0]
    failures = ", ".join(f"{r} {int(row[f'failures_{r}'])}" for r in H.FAILURE_REASONS if row[f"failures_{r}"])
    summary = (f"Evaluated {label} (low level {low_level}) on {episodes} episodes of ToolPick-v0 with a "
               f"{object} of {size * 100:g} cm, {perception} perception{noted}, seed {seed}: success within 200 steps "
               f"(object within 1 cm of the target, the episodes' recorded verdict) {int(row['successes'])}/"
               f"{episodes} = {row['success_rate']:.2f} [{row['ci_low']:.2f}, {row['ci_high']:.2f}], at the first "
               f"attempt {int(row['first_attempt_successes'])}/{episodes} = {row['first_attempt_success_rate']:.2f} "
               f"[{row['first_attempt_ci_low']:.2f}, {row['first_attempt_ci_high']:.2f}], mean attempts "
               f"{row['mean_attempts']:.2f}; failures: {failures or 'none'}. Dataset, episodes.csv, table.csv, "
               f"report.md in {out}.")
    (out / "report.md").write_text(
        f"# High-level evaluation of {label}\n\n{episodes} episodes, seed {seed} (episode i reset with "
        f"seed {H.SEED_BASE} + {seed} * {H.SEED_STRIDE} + i, the same for every policy), low level "
        f"{low_level}. `success`: the env's verdict, object within 1 cm of the target within 200 steps; "
        f"`first_attempt_`: that before any grasp was lost; intervals are Wilson 95%; failure reasons as in "
        f"`hingelab.rollouts.high_level`.\n\n" + markdown_table(table.round(3)) + "\n\n" + summary + "\n")
    return Evaluation(out, label, rows, table, summary, {"low_level": low_level})


__all__ = ["Evaluation", "evaluate_low", "evaluate_high", "stop_cleanly_on_a_full_disk"]
