"""Evaluating a low-level policy: fixed or sampled reachable goals, deterministic actions.

An episode succeeds by the env's one verdict, ``info["is_success"]`` at its last step (the
recorded ``success``): ToolShape-v0's smoothed latent averaged over the last 0.5 s
(``SETTLE_STEPS``, owned by the env) within the success threshold of the goal, so the tool
must *stay* shaped, not pass through the goal. ``run_episode`` also gives the one-frame
verdict as ``last_step_success`` (secondary, never counted as success) and the privileged
tip-gap error. Tool drift is the privileged distance of the tool from
where the episode started (hand frame), its maximum over the episode. ``HoldStillPolicy``
and ``SynergyPolicy`` are the references (``reference_policy``).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
from tqdm import tqdm

from hingelab.analysis.wilson import wilson_interval
from hingelab.envs.recording import RecordingWrapper
from hingelab.envs.rewards import LowLevelRewardConfig
from hingelab.envs.tool_shape import SETTLE_STEPS
from hingelab.rollouts.low_level_goals import REGIONS, region_of
from hingelab.seeds import sampled_goal_seed
from hingelab.tasks import TOOL_SHAPE_ID as ENV_ID


def recorded_env_arguments(model) -> dict:
    """The ToolShape-v0 arguments a low-level checkpoint was trained with: its record (``env_kwargs``,
    written since the training core), or, for older checkpoints, rebuilt from its config (the reward's
    weights and the episode length; the defaults where the config is silent)."""
    provenance = getattr(model, "hingelab_provenance", None) or {}
    if isinstance(provenance.get("env_kwargs"), dict):
        return dict(provenance["env_kwargs"])
    trained = provenance.get("config", {})
    return {"use_effort": trained.get("use_effort", True),
            "effort_weight": trained.get("effort_weight", LowLevelRewardConfig().c2),
            "drift_weight": trained.get("drift_weight", 0.0),
            "max_episode_steps": trained.get("max_episode_steps", 50)}


TRAINING_ONLY_ARGUMENTS = ("goal_sampling", "goal_openings")  # a run's training goals, not an evaluation's


def evaluation_env_arguments(model) -> dict:
    """``recorded_env_arguments`` without the training goals: held-out goals come from the whole
    reachable range, whatever band the policy was trained on."""
    return {k: v for k, v in recorded_env_arguments(model).items() if k not in TRAINING_ONLY_ARGUMENTS}


def run_episode(policy, env: gym.Env, goal: dict) -> dict:
    """One deterministic episode toward ``goal`` (dict with z_goal, seed, region, opening_rad).

    ``success`` is the env's verdict at the last step (``info["is_success"]``: z_bar averaged
    over the last SETTLE_STEPS steps within the threshold; ``settled_latent_distance`` that
    mean's distance), the same the recording wrapper writes as the episode's ``success``;
    ``last_step_success`` and ``final_latent_distance`` are the last frame's alone (secondary:
    one frame's z carries the perception's jitter, about as large as the threshold itself:
    ``analysis/low-level-ablation/README.md``); ``tip_gap_error_mm`` is the privileged truth: the tips' gap over the
    last SETTLE_STEPS steps against the gap of the goal's calibrated opening.
    """
    obs, info = env.reset(seed=int(goal["seed"]), options={"goal": goal["z_goal"]})
    if hasattr(policy, "reset"):  # scripted references keep per-episode state
        policy.reset()
    unwrapped = env.unwrapped
    total, steps, drift_max, done = 0.0, 0, 0.0, False
    gaps = []
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        drift_max = max(drift_max, float(info["tool_drift_m"]))
        gaps.append(float(unwrapped.state.tip_gap))
        done = terminated or truncated
    goal_gap_mm = float(unwrapped.calibration.tip_gap_mm_for_opening(goal["opening_rad"]))
    return {"region": goal["region"], "goal_opening_rad": goal["opening_rad"], "seed": int(goal["seed"]),
            "success": bool(info["is_success"]), "settled_latent_distance": float(info["settled_latent_distance"]),
            "last_step_success": bool(info["last_step_success"]),
            "final_latent_distance": float(info["latent_distance"]),
            "tip_gap_error_mm": abs(1000.0 * float(np.mean(gaps[-SETTLE_STEPS:])) - goal_gap_mm),
            "final_hinge_rad": float(info["hinge_angle"]), "return": total, "length": steps,
            "tool_drift_mm_max": 1000 * drift_max, "failure_reason": info.get("failure_reason", "")}


def evaluate(policy, env: gym.Env, goals: list[dict]) -> pd.DataFrame:
    return pd.DataFrame([run_episode(policy, env, g) for g in goals])


def summarize(episodes: pd.DataFrame) -> dict:
    """The metrics row of one evaluation (``metrics.csv`` columns beyond env_steps/seed).

    ``success_rate`` counts the env's verdict (settled); ``last_step_success_rate`` the
    secondary one-frame verdict. (``metrics.csv`` files written before episode schema 2 have
    ``success_rate`` = last step and ``settled_success_rate``; ``hingelab report`` reads them
    under these names: ``hingelab.analysis.learning_curves``.)
    """
    under_1cm = episodes["tool_drift_mm_max"] < 10
    out = {
        "success_rate": float(episodes["success"].mean()),
        "return": float(episodes["return"].mean()),
        "final_latent_distance": float(episodes["final_latent_distance"].mean()),
        "settled_latent_distance": float(episodes["settled_latent_distance"].mean()),
        "tool_drift_mm_max": float(episodes["tool_drift_mm_max"].max()),
        "tool_drift_mm_mean": float(episodes["tool_drift_mm_max"].mean()),
        "success_under_1cm": float((episodes["success"] & under_1cm).mean()),
        "last_step_success_rate": float(episodes["last_step_success"].mean()),
        "last_step_success_under_1cm": float((episodes["last_step_success"] & under_1cm).mean()),
        "tip_gap_error_mm_median": float(episodes["tip_gap_error_mm"].median()),
    }
    for region in REGIONS:
        part = episodes[episodes["region"] == region]
        out[f"success_{region}"] = float(part["success"].mean()) if len(part) else float("nan")
    return out


def region_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per goal region and overall: episodes, the success verdict (``successes``, ``success_rate``,
    ``ci_low``, ``ci_high``: the env's, settled) and the secondary one-frame verdict (``last_step_``
    prefix), each with Wilson 95% intervals and with the tool's drift under 1 cm; distances, truth."""
    rows = []
    for region in (*REGIONS, "all"):
        part = episodes if region == "all" else episodes[episodes["region"] == region]
        if not len(part):
            continue
        n = len(part)
        row = {"goal_region": region, "episodes": n}
        for verdict, prefix in (("success", ""), ("last_step_success", "last_step_")):
            k = int(part[verdict].sum())
            low, high = wilson_interval(np.array([k]), np.array([n]))
            row |= {f"{prefix}successes": k, f"{prefix}success_rate": k / n,
                    f"{prefix}ci_low": float(low[0]), f"{prefix}ci_high": float(high[0]),
                    f"{prefix}success_and_drift_under_1cm":
                        float((part[verdict] & (part["tool_drift_mm_max"] < 10)).mean())}
        row |= {"final_latent_distance": float(part["final_latent_distance"].mean()),
                "settled_latent_distance": float(part["settled_latent_distance"].mean()),
                "tip_gap_error_mm_median": float(part["tip_gap_error_mm"].median()),
                "tool_drift_mm_max_median": float(part["tool_drift_mm_max"].median())}
        rows.append(row)
    return pd.DataFrame(rows)


def evaluate_sampled_goals(policy, env: gym.Env, episodes: int, seed: int, progress: bool = False,
                           journal=None) -> pd.DataFrame:
    """``episodes`` reachable goals (``sampled_goals``), one episode each, in order; each episode's goal
    region and opening go into a recording env's metadata. One row per episode (``run_episode``).
    ``journal`` (``eval_journal.EpisodeJournal``): its rows are kept, their goals not run again."""

    unwrapped = env.unwrapped
    goals = sampled_goals(unwrapped.calibration, unwrapped.reachable_range, episodes, seed)
    rows = list(journal.rows) if journal is not None else []
    done = {int(r["seed"]) for r in rows}
    with tqdm(goals, desc="eval low", unit="episode", disable=not progress) as bar:
        for goal in bar:
            if int(goal["seed"]) in done:
                continue
            env.extra_metadata = {"goal_region": goal["region"], "goal_opening_rad": f"{goal['opening_rad']:.5f}"}
            row = run_episode(policy, env, goal)
            if journal is not None:
                journal.append(row)
            rows.append(row)
            bar.set_postfix(success=f"{sum(r['success'] for r in rows) / len(rows):.2f}")
    order = {int(g["seed"]): k for k, g in enumerate(goals)}
    return pd.DataFrame(rows).sort_values("seed", key=lambda s: s.map(order), ignore_index=True)


def sampled_goals(calibration, reachable_range, n: int, seed: int) -> list[dict]:
    """``n`` reachable goals, stratified uniform over the opening range (seeded), each its own episode seed."""
    rng = np.random.default_rng(seed)
    low, high = reachable_range
    openings = low + (np.arange(n) + rng.uniform(size=n)) / n * (high - low)
    rng.shuffle(openings)
    return [{"region": region_of(o, reachable_range), "opening_rad": float(o),
             "z_goal": np.asarray(calibration.z_for_opening(o), float),
             "seed": sampled_goal_seed(seed, i)} for i, o in enumerate(openings)]


def make_eval_env(env_arguments: dict, record_dir: Path | None = None, source: str = "low_level_evaluation"):
    env = gym.make(ENV_ID, **env_arguments)
    if record_dir is not None:

        env = RecordingWrapper(env, record_dir, source=source, action_level="low")
    return env
