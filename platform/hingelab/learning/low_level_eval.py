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

from hingelab.analysis.wilson import wilson_interval
from hingelab.envs.tool_shape import SETTLE_STEPS
from hingelab.learning.low_level_config import ENV_ID
from hingelab.learning.low_level_envs import EVAL_SEED_BASE, REGIONS, region_of


class HoldStillPolicy:
    """The do-nothing baseline: zero finger changes. It "succeeds" whenever the goal happens to
    lie near the opening the hand holds at rest, so a learned policy must beat its rate."""

    hingelab_provenance = {"policy": "hold still (zero action)"}

    def predict(self, obs, deterministic: bool = True):
        return np.zeros(9, dtype=np.float32), None


class SynergyPolicy:
    """The scripted reference: z_goal -> opening (the encoder's calibration) -> the grasp
    synergy's finger targets, approached at the action limit, with integral feedback on
    the latent: the commanded opening moves by ``feedback`` times the latent error along
    the calibration axis (converted to rad by the curve's mean slope) every step, which
    removes the offset between the calibration and the in-hand latent and the gain and
    friction randomization. ``feedback=0``: open loop. It sees only what a policy sees
    (the goal latent, z_bar, the delayed hand q), so its success rate is what a
    hand-written controller reaches through the same perception; its episodes make
    demonstration datasets for ``hingelab train low --from``."""

    hingelab_provenance = {"policy": "scripted synergy (calibrated opening -> finger targets, latent feedback)"}

    def __init__(self, calibration, action_scale: float = 0.05, squeeze: float = 0.03, feedback: float = 0.2):
        from hingelab.sim.finger_synergy import FingerSynergy

        self.calibration, self.action_scale, self.squeeze = calibration, action_scale, squeeze
        self.synergy = FingerSynergy.load()
        self.feedback = feedback
        low, high = self.synergy.theta_range
        self.bounds = (max(low, 0.0) - 0.05, high + 0.05)  # room past the table for the integral to act
        span = np.diff(calibration.coordinate(calibration.z_for_opening(np.array([low, high]))))[0]
        self.per_rad = float(span / (high - low))  # latent coordinate per rad of opening
        self.command = None

    def reset(self) -> None:
        self.command = None

    def predict(self, obs, deterministic: bool = True):
        goal = np.asarray(obs["desired_goal"], float)
        if self.command is None:
            # goals are points of the calibration curve: their own opening (as the demonstrations were made)
            self.command = float(self.calibration.project_opening(goal))
        error = float(self.calibration.coordinate(goal) - self.calibration.coordinate(obs["achieved_goal"]))
        self.command = float(np.clip(self.command + self.feedback * error / self.per_rad, *self.bounds))
        targets = self.synergy.targets(self.command - self.squeeze)
        q = np.asarray(obs["observation"], float)[:9]
        return np.clip((targets - q) / self.action_scale, -1, 1).astype(np.float32), None


REFERENCES = ("hold-still", "synergy")


def reference_policy(name: str, env: gym.Env):
    """A reference by name (``REFERENCES``) for ``env`` (a ToolShape-v0, possibly wrapped)."""
    unwrapped = env.unwrapped
    if name == "hold-still":
        return HoldStillPolicy()
    if name == "synergy":
        return SynergyPolicy(unwrapped.calibration, action_scale=unwrapped.action_scale)
    raise ValueError(f"unknown reference policy {name!r}; choose one of {REFERENCES}")


def run_episode(policy, env: gym.Env, goal: dict) -> dict:
    """One deterministic episode toward ``goal`` (dict with z_goal, seed, region, opening_rad).

    ``success`` is the env's verdict at the last step (``info["is_success"]``: z_bar averaged
    over the last SETTLE_STEPS steps within the threshold; ``settled_latent_distance`` that
    mean's distance), the same the recording wrapper writes as the episode's ``success``;
    ``last_step_success`` and ``final_latent_distance`` are the last frame's alone (secondary:
    one frame's z carries the perception's jitter, 0.04 to 0.10 latent rms at rest, about the
    threshold itself); ``tip_gap_error_mm`` is the privileged truth: the tips' gap over the
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
    from tqdm import tqdm

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
             "seed": EVAL_SEED_BASE + 1_000_000 + seed * 10_007 + i} for i, o in enumerate(openings)]


def make_eval_env(env_arguments: dict, record_dir: Path | None = None, source: str = "low_level_evaluation"):
    env = gym.make(ENV_ID, **env_arguments)
    if record_dir is not None:
        from hingelab.envs.recording import RecordingWrapper

        env = RecordingWrapper(env, record_dir, source=source, action_level="low")
    return env
