"""Evaluating a low-level policy: fixed or sampled reachable goals, deterministic actions.

An episode succeeds when its smoothed latent ends within the env's success threshold of
the goal (``info["is_success"]`` at the last step: the tool must *stay* shaped, not pass
through the goal). Tool drift is the privileged distance of the tool from where the
episode started (hand frame), its maximum over the episode.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

from hingelab.analysis.wilson import wilson_interval
from hingelab.learning.low_level_config import ENV_ID
from hingelab.learning.low_level_envs import EVAL_SEED_BASE, REGIONS, region_of


def run_episode(policy, env: gym.Env, goal: dict) -> dict:
    """One deterministic episode toward ``goal`` (dict with z_goal, seed, region, opening_rad)."""
    obs, info = env.reset(seed=int(goal["seed"]), options={"goal": goal["z_goal"]})
    total, steps, drift_max, done = 0.0, 0, 0.0, False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        drift_max = max(drift_max, float(info["tool_drift_m"]))
        done = terminated or truncated
    return {"region": goal["region"], "goal_opening_rad": goal["opening_rad"], "seed": int(goal["seed"]),
            "success": bool(info["is_success"]), "final_latent_distance": float(info["latent_distance"]),
            "final_hinge_rad": float(info["hinge_angle"]), "return": total, "length": steps,
            "tool_drift_mm_max": 1000 * drift_max, "failure_reason": info.get("failure_reason", "")}


def evaluate(policy, env: gym.Env, goals: list[dict]) -> pd.DataFrame:
    return pd.DataFrame([run_episode(policy, env, g) for g in goals])


def summarize(episodes: pd.DataFrame) -> dict:
    """The metrics row of one evaluation (``metrics.csv`` columns beyond env_steps/seed)."""
    out = {
        "success_rate": float(episodes["success"].mean()),
        "return": float(episodes["return"].mean()),
        "final_latent_distance": float(episodes["final_latent_distance"].mean()),
        "tool_drift_mm_max": float(episodes["tool_drift_mm_max"].max()),
        "tool_drift_mm_mean": float(episodes["tool_drift_mm_max"].mean()),
        "success_under_1cm": float((episodes["success"] & (episodes["tool_drift_mm_max"] < 10)).mean()),
    }
    for region in REGIONS:
        part = episodes[episodes["region"] == region]
        out[f"success_{region}"] = float(part["success"].mean()) if len(part) else float("nan")
    return out


def region_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per goal region and overall: episodes, successes, rate, Wilson 95% interval, drift."""
    rows = []
    for region in (*REGIONS, "all"):
        part = episodes if region == "all" else episodes[episodes["region"] == region]
        if not len(part):
            continue
        n, k = len(part), int(part["success"].sum())
        low, high = wilson_interval(np.array([k]), np.array([n]))
        rows.append({"goal_region": region, "episodes": n, "successes": k, "success_rate": k / n,
                     "ci_low": float(low[0]), "ci_high": float(high[0]),
                     "success_and_drift_under_1cm": float((part["success"] & (part["tool_drift_mm_max"] < 10)).mean()),
                     "final_latent_distance": float(part["final_latent_distance"].mean()),
                     "tool_drift_mm_max_median": float(part["tool_drift_mm_max"].median())})
    return pd.DataFrame(rows)


def sampled_goals(calibration, reachable_range, n: int, seed: int) -> list[dict]:
    """``n`` reachable goals, stratified uniform over the opening range (seeded), each its own episode seed."""
    rng = np.random.default_rng(seed)
    low, high = reachable_range
    openings = low + (np.arange(n) + rng.uniform(size=n)) / n * (high - low)
    rng.shuffle(openings)
    return [{"region": region_of(o, reachable_range), "opening_rad": float(o),
             "z_goal": np.asarray(calibration.z_for_opening(o), float),
             "seed": EVAL_SEED_BASE + 1_000_000 + seed * 10_007 + i} for i, o in enumerate(openings)]


def make_eval_env(env_arguments: dict, record_dir: Path | None = None, source: str = "low_level_evaluation"):
    env = gym.make(ENV_ID, **env_arguments)
    if record_dir is not None:
        from hingelab.envs.recording import RecordingWrapper

        env = RecordingWrapper(env, record_dir, source=source, action_level="low")
    return env
