"""Why does a fine-tuned residual pick less than its base? ``hingelab diagnose residual CHECKPOINT``.

A residual learner maximizes the discounted return its critic estimates. When its policy picks less than its
base, either the reward pays for something other than picking (the true discounted return rises while success
falls: fix the reward), or the learner failed at its own objective (the true return falls too: the critics'
errors drove the actor, fix the learner). This tells the two apart on episodes the run never saw, paired by
reset seed, and names the action dimensions the harm comes from:

* arms: the base alone; the residual policy; the residual with one action group zeroed at a time
  (``z_goal``: the latent goal, ``velocity_xy``, ``velocity_z``: the hand's velocity);
* per arm: success (the env's verdict), the true discounted value of the start state (``v0``: the episode's
  rewards discounted with the run's gamma, a time-limit cut bootstrapped with its last reward held forever,
  as a critic's fixed point values it) and of every visited state (``v_visited``), table collisions;
* the verdict compares the residual with its base on success and on ``v0`` (paired, with the standard error
  of the paired difference).
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from hingelab.envs import TOOL_PICK_ID
from hingelab.envs.rewards import HighLevelRewardConfig
from hingelab.errors import ConfigError
from hingelab.policies.high_level import observation_form
from hingelab.policies.loading import load_policy
from hingelab.policies.policy import ModelPolicy
from hingelab.policies.residual import ResidualPolicy
from hingelab.rollouts.high_level import FailureReasonWrapper
from hingelab.rollouts.reward_diagnostic import discounted_values, write_tables
from hingelab.seeds import eval_high_seed

#: action dimensions by group (the high level's action: latent goal 0-1, hand velocity x, y, z)
GROUPS = {"z_goal": (0, 1), "velocity_xy": (2, 3), "velocity_z": (4,)}


def without(policy: ResidualPolicy, dims) -> ResidualPolicy:
    """``policy`` with its residual zeroed on ``dims`` (those dimensions act as the base)."""
    masked = copy.copy(policy)
    scale = np.array(policy.scale, copy=True)
    scale[list(dims)] = 0.0
    masked.scale = scale
    return masked


def arms(policy: ResidualPolicy) -> dict:
    return {"base": policy.base, "residual": policy,
            **{f"residual without {name}": without(policy, dims) for name, dims in GROUPS.items()}}


def run_arm(model, env, episodes: int, seed: int, gamma: float, label: str, progress: bool) -> list[dict]:
    acting, rows = ModelPolicy(model), []
    for i in tqdm(range(episodes), desc=label, unit="episode", disable=not progress):
        episode_seed = eval_high_seed(seed, i)
        obs, info = env.reset(seed=episode_seed)
        acting.reset(env, episode_seed)
        rewards, collisions = [], 0
        while True:
            obs, reward, terminated, truncated, info = env.step(acting.act(env, obs))
            rewards.append(float(reward))
            collisions += bool(info.get("table_collision", False))
            if terminated or truncated:
                break
        values = discounted_values(rewards, bool(truncated and not terminated), gamma)
        success = bool(info.get("is_success", 0.0))
        rows.append({"arm": label, "episode": i, "seed": episode_seed, "success": success,
                     "failure_reason": "" if success else info.get("failure_reason", ""), "length": len(rewards),
                     "return": float(np.sum(rewards)), "v0": float(values[0]), "v_visited": float(values.mean()),
                     "table_collision_steps": collisions})
    return rows


def diagnose(checkpoint, object: str, size: float, episodes: int = 30, seed: int = 100, gamma: float | None = None,
             progress: bool = True) -> tuple[list[dict], float]:
    """Episode rows of every arm (module doc) and the gamma they were valued with."""
    if episodes < 2:
        raise ConfigError(f"--episodes must be at least 2 (a paired standard error), not {episodes}")
    model = load_policy(checkpoint, level="high")
    if not isinstance(model, ResidualPolicy):
        raise ConfigError(f"{checkpoint} is not a residual policy; give a checkpoint of `hingelab train high "
                          "--learner residual-sac` (RUNDIR/model.zip or RUNDIR/checkpoints/step_N)")
    recorded = model.hingelab_provenance
    config = recorded.get("config") or {}
    if isinstance(config, str):  # an SB3 zip's plain data keeps nested dicts as their repr
        config = {}
    gamma = float(gamma if gamma is not None else config.get("gamma", 0.98))
    reward = HighLevelRewardConfig(mode=config.get("reward_mode", "absorbing"), gamma=gamma)
    env = FailureReasonWrapper(gym.make(TOOL_PICK_ID, object=object, size=size,
                                        low_level=recorded.get("low_level", "policy"), max_episode_steps=200,
                                        **observation_form(model), reward=asdict(reward)))
    rows = []
    try:
        for label, arm in arms(model).items():
            rows += run_arm(arm, env, episodes, seed, gamma, label, progress)
    finally:
        env.close()
    return rows, gamma


def summarize(rows: list[dict]) -> list[dict]:
    base = {r["episode"]: r for r in rows if r["arm"] == "base"}
    out = []
    for arm in dict.fromkeys(r["arm"] for r in rows):
        mine = [r for r in rows if r["arm"] == arm]
        diff = np.array([r["v0"] - base[r["episode"]]["v0"] for r in mine])
        out.append({"arm": arm, "episodes": len(mine), "successes": sum(r["success"] for r in mine),
                    "success_rate": round(float(np.mean([r["success"] for r in mine])), 3),
                    "v0": round(float(np.mean([r["v0"] for r in mine])), 2),
                    "v0_minus_base": round(float(diff.mean()), 2),
                    "v0_minus_base_se": round(float(diff.std(ddof=1) / math.sqrt(len(diff))), 2),
                    "v_visited": round(float(np.mean([r["v_visited"] for r in mine])), 2),
                    "episodes_with_table_collision": sum(r["table_collision_steps"] > 0 for r in mine)})
    return out


def verdict(summary: list[dict]) -> str:
    by = {s["arm"]: s for s in summary}
    base, residual = by["base"], by["residual"]
    picks = residual["successes"] - base["successes"]
    dv, se = residual["v0_minus_base"], residual["v0_minus_base_se"]
    value = "higher" if dv > 2 * se else "lower" if dv < -2 * se else "no different (within 2 standard errors)"
    if picks < 0 and dv < -2 * se:
        cause = ("the learner failed at its own objective: the true discounted return fell with success, so the "
                 "critics' errors drove the actor (fix the learner, not the reward)")
    elif picks < 0 and dv > 2 * se:
        cause = "the reward pays the residual for what costs picks (fix the reward)"
    elif picks < 0:
        cause = "the residual costs picks without a measurable change of the true return"
    else:
        cause = "the residual does not cost picks here"
    groups = [s for s in summary if s["arm"].startswith("residual without")]
    best = max(groups, key=lambda s: (s["successes"], s["v0"]))
    harm = (f"Zeroing {best['arm'][len('residual without '):]} recovers the most: {best['successes']} picks "
            f"against the residual's {residual['successes']} and the base's {base['successes']}.")
    return (f"The residual picks {residual['successes']} of {residual['episodes']}, its base {base['successes']}; "
            f"its true discounted value of the start is {value} ({dv:+.2f} +- {se:.2f}): {cause}. {harm}")


def write_report(rows: list[dict], summary: list[dict], out: Path, command: str, gamma: float) -> Path:
    out = write_tables(out, {"episodes.csv": rows, "summary.csv": summary})
    columns = list(summary[0])
    lines = ["# Why the fine-tuned residual picks less than its base", "",
             f"Made by `{command}` (`hingelab.rollouts.residual_diagnostic`). Each arm runs the same reset seeds. "
             f"`v0`: the true discounted value (gamma {gamma:g}) of the start state, the quantity the learner "
             "maximizes; `v0_minus_base`: paired by seed, with its standard error; `v_visited`: the mean over every "
             "visited state.", "",
             "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(s[c]) for c in columns) + " |" for s in summary]
    lines += ["", verdict(summary)]
    path = out / "residual_diagnostic.md"
    path.write_text("\n".join(lines) + "\n")
    return path


__all__ = ["diagnose", "summarize", "verdict", "write_report", "discounted_values", "without", "GROUPS"]
