"""How large a consistent offset each high-level action dimension of a policy tolerates: ``hingelab diagnose bias``.

A residual learner's correction is not noise that averages out over an episode: it is a state-dependent
offset that the base executes step after step, and a few millimetres per second on the hand's velocity add
up to millimetres of position over an approach. ``diagnose noise`` measures what i.i.d. exploration noise
each dimension tolerates; this measures what a constant offset does to a policy (default the shipped
clone, the residual's base): the policy drives with ``+level`` and with ``-level`` added to one executed
action dimension at a time, the same reset seeds for every level. A dimension tolerates a level when both
signs keep success within ``MARGIN`` of the offset-free rate with at most ``MAX_DROPS`` tool drops; its
tolerance is the largest level at and below which every level is tolerated. A residual whose reach on a
dimension is far above it can drift, within its bound, into a policy that picks less.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from hingelab.envs import TOOL_PICK_ID
from hingelab.errors import ConfigError
from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL, observation_form
from hingelab.policies.loading import load_policy
from hingelab.policies.policy import ModelPolicy
from hingelab.rollouts.high_level import FailureReasonWrapper
from hingelab.rollouts.noise_tolerance import DIMENSIONS, MARGIN, MAX_DROPS, tolerance_table
from hingelab.rollouts.reward_diagnostic import write_tables
from hingelab.seeds import eval_high_seed

DEFAULT_LEVELS = (0.01, 0.025, 0.05)


def run_offset(env, model, offset: np.ndarray, seeds) -> dict:
    acting = ModelPolicy(model)
    successes = drops = 0
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        acting.reset(env, seed)
        while True:
            action = np.clip(np.asarray(acting.act(env, obs), np.float32) + offset, -1, 1).astype(np.float32)
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        successes += bool(info["is_success"])
        drops += bool(info.get("tool_dropped")) and not info["is_success"]
    return {"episodes": len(seeds), "successes": successes, "tool_drops": drops}


def measure(checkpoint=None, episodes: int = 30, levels=DEFAULT_LEVELS, dimensions=DIMENSIONS, seed: int = 100,
            object: str = "sphere", size: float = 0.02, progress: bool = True) -> list[dict]:
    """One row per (dimension, signed offset), and the offset-free row (dimension "none", offset 0)."""
    levels = sorted(float(v) for v in levels)
    unknown = [d for d in dimensions if d not in DIMENSIONS]
    if episodes < 1 or not levels or min(levels) <= 0 or unknown or not dimensions:
        raise ConfigError(f"give --episodes >= 1, positive --levels and --dimensions among {', '.join(DIMENSIONS)}; "
                          f"not {episodes}, {levels}, {list(dimensions)}")
    model = load_policy(checkpoint or SHIPPED_HIGH_LEVEL, level="high")
    low_level = (getattr(model, "hingelab_provenance", None) or {}).get("low_level", "policy")
    seeds = [eval_high_seed(seed, i) for i in range(episodes)]
    env = FailureReasonWrapper(gym.make(TOOL_PICK_ID, object=object, size=size, low_level=low_level,
                                        max_episode_steps=200, **observation_form(model)))
    rows = []
    try:
        bar = tqdm(total=(1 + 2 * len(dimensions) * len(levels)) * episodes, desc="diagnose bias", unit="episode",
                   disable=not progress)
        rows.append({"dimension": "none", "offset": 0.0, **run_offset(env, model, np.zeros(5, np.float32), seeds)})
        bar.update(episodes)
        for name in dimensions:
            for level in levels:
                for sign in (-1.0, 1.0):
                    offset = np.zeros(5, np.float32)
                    offset[DIMENSIONS.index(name)] = sign * level
                    rows.append({"dimension": name, "offset": sign * level, **run_offset(env, model, offset, seeds)})
                    bar.update(episodes)
        bar.close()
    finally:
        env.close()
    return rows


def tolerances(rows: list[dict]) -> dict[str, float]:
    """Per measured dimension: the largest level such that it and every lower level is tolerated at both signs."""
    clean = next(r for r in rows if r["dimension"] == "none")
    clean_rate = clean["successes"] / clean["episodes"]
    out = {}
    for name in dict.fromkeys(r["dimension"] for r in rows if r["dimension"] != "none"):
        tolerated = 0.0
        for level in sorted({abs(r["offset"]) for r in rows if r["dimension"] == name}):
            both = [r for r in rows if r["dimension"] == name and abs(r["offset"]) == level]
            if any(r["successes"] / r["episodes"] < clean_rate - MARGIN or r["tool_drops"] > MAX_DROPS for r in both):
                break
            tolerated = level
        out[name] = tolerated
    return out


def write_report(rows: list[dict], out: Path, command: str, policy: str) -> Path:
    out = write_tables(out, {"bias_tolerance.csv": rows})
    tolerated = tolerances(rows)
    clean = next(r for r in rows if r["dimension"] == "none")
    lines = ["# A consistent offset each high-level action dimension tolerates", "",
             f"Made by `{command}` (`hingelab.rollouts.bias_tolerance`). {policy} with a constant offset (action "
             "units) on one executed action dimension at a time, the same "
             f"{clean['episodes']} reset seeds at every offset. Offset-free: {clean['successes']} of "
             f"{clean['episodes']} picked, {clean['tool_drops']} tool drops. Cells: successes / tool drops.", "",
             *tolerance_table(rows, "offset", tolerated, lambda v: f"{v:+g}")]
    lines += ["", f"Tolerated: the largest level at and below which both signs keep success within {MARGIN:g} of the "
                  f"offset-free rate and at most {MAX_DROPS} episode(s) end in a tool drop."]
    path = out / "bias_tolerance.md"
    path.write_text("\n".join(lines) + "\n")
    return path


__all__ = ["measure", "tolerances", "write_report", "DEFAULT_LEVELS"]
