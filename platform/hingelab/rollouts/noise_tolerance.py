"""How much exploration noise each high-level action dimension tolerates: ``hingelab diagnose noise``.

SAC explores by executing its action with Gaussian noise (before the tanh); on ToolPick-v0 that noise
lands on the latent goal the frozen low level chases and on the hand's velocity. Too much on the latent
makes the low level shake the tool out of the hand (the scripted demonstrator with 0.1 on it dropped the
tool in most demos). Here the scripted demonstrator (``eval high --baseline scripted``) drives with
Gaussian noise of a given std (action units, clipped to [-1, 1]) on one action dimension at a time,
``episodes`` episodes per level, the same reset seeds at every level. A dimension tolerates a level when
its success rate stays within ``MARGIN`` of the noise-free rate and at most ``MAX_DROPS`` episodes end
in a tool drop; its tolerance is the largest level below which every level is tolerated. Learners bound
their exploration below it (``hingelab.learners.residual``).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from hingelab.envs import TOOL_PICK_ID
from hingelab.errors import ConfigError
from hingelab.policies.baselines import ScriptedPolicy
from hingelab.rollouts.reward_diagnostic import write_tables
from hingelab.seeds import eval_high_seed
from hingelab.tasks import HIGH_LEVEL_ACTION_NAMES

DIMENSIONS = HIGH_LEVEL_ACTION_NAMES  # ToolPick-v0's action
DEFAULT_LEVELS = (0.02, 0.05, 0.1, 0.2, 0.3)
MARGIN = 0.1  # success within this of the noise-free rate
MAX_DROPS = 1  # tool drops among a level's episodes


class NoisyScriptedPolicy(ScriptedPolicy):
    """The scripted demonstrator with Gaussian noise of std ``std[d]`` on each executed action dimension d."""

    def __init__(self, std):
        self.std = np.asarray(std, float)

    def reset(self, env, seed: int) -> None:
        super().reset(env, seed)
        self.exploration = np.random.default_rng([seed, 0x5E1])  # apart from the env's and the DART noise

    def act(self, env, obs) -> np.ndarray:
        action = super().act(env, obs)
        return np.clip(action + self.exploration.normal(0.0, 1.0, 5) * self.std, -1, 1).astype(np.float32)


def run_level(env, std, seeds) -> dict:
    policy = NoisyScriptedPolicy(std)
    successes = drops = 0
    for seed in seeds:
        env.reset(seed=seed)
        policy.reset(env, seed)
        obs = None
        while True:
            obs, _, terminated, truncated, info = env.step(policy.act(env, obs))
            if terminated or truncated:
                break
        successes += bool(info["is_success"])
        drops += bool(info.get("tool_dropped")) and not info["is_success"]
    return {"episodes": len(seeds), "successes": successes, "tool_drops": drops}


def measure(episodes: int = 20, levels=DEFAULT_LEVELS, seed: int = 9200, object: str = "sphere", size: float = 0.02,
            progress: bool = True) -> list[dict]:
    """One row per (dimension, level), and the noise-free row (dimension "none", level 0)."""
    levels = sorted(float(v) for v in levels)
    if episodes < 1 or not levels or min(levels) <= 0:
        raise ConfigError(f"give --episodes >= 1 and positive --levels, not {episodes} and {levels}")
    seeds = [eval_high_seed(seed, i) for i in range(episodes)]
    env = gym.make(TOOL_PICK_ID, object=object, size=size)
    rows = []
    try:
        bar = tqdm(total=(1 + len(DIMENSIONS) * len(levels)) * episodes, desc="diagnose noise", unit="episode",
                   disable=not progress)
        clean = run_level(env, np.zeros(5), seeds)
        bar.update(episodes)
        rows.append({"dimension": "none", "level": 0.0, **clean})
        for d, name in enumerate(DIMENSIONS):
            for level in levels:
                std = np.zeros(5)
                std[d] = level
                rows.append({"dimension": name, "level": level, **run_level(env, std, seeds)})
                bar.update(episodes)
        bar.close()
    finally:
        env.close()
    return rows


def tolerances(rows: list[dict]) -> dict[str, float]:
    """Per dimension: the largest level such that it and every lower level is tolerated (module doc); 0 when
    the lowest level is not."""
    clean = next(r for r in rows if r["dimension"] == "none")
    clean_rate = clean["successes"] / clean["episodes"]
    out = {}
    for name in DIMENSIONS:
        tolerated = 0.0
        for r in sorted((r for r in rows if r["dimension"] == name), key=lambda r: r["level"]):
            if r["successes"] / r["episodes"] < clean_rate - MARGIN or r["tool_drops"] > MAX_DROPS:
                break
            tolerated = r["level"]
        out[name] = tolerated
    return out


def tolerance_table(rows: list[dict], key: str, tolerated: dict[str, float], label) -> list[str]:
    """Markdown rows: a dimension per row, a ``key`` value per column (headed ``label(value)``), cells
    "successes / tool drops", and the tolerated level last."""
    values = sorted({r[key] for r in rows if r["dimension"] != "none"})
    lines = ["| dimension | " + " | ".join(label(v) for v in values) + " | tolerated |",
             "|---|" + "---|" * (len(values) + 1)]
    for name, level in tolerated.items():
        cells = [next(f"{r['successes']} / {r['tool_drops']}" for r in rows if r["dimension"] == name and r[key] == v)
                 for v in values]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {level:g} |")
    return lines


def write_report(rows: list[dict], out: Path, command: str) -> Path:
    out = write_tables(out, {"noise_tolerance.csv": rows})
    tolerated = tolerances(rows)
    clean = next(r for r in rows if r["dimension"] == "none")
    lines = ["# Exploration noise each high-level action dimension tolerates", "",
             f"Made by `{command}` (`hingelab.rollouts.noise_tolerance`). The scripted demonstrator over the shipped "
             "low level with Gaussian noise (std in action units) on one executed action dimension at a time, the "
             f"same {clean['episodes']} reset seeds at every level. Noise-free: {clean['successes']} of "
             f"{clean['episodes']} picked, {clean['tool_drops']} tool drops. Cells: successes / tool drops.", "",
             *tolerance_table(rows, "level", tolerated, lambda v: f"std {v:g}")]
    lines += ["", f"Tolerated: the largest level at and below which success stays within {MARGIN:g} of the "
                  f"noise-free rate and at most {MAX_DROPS} episode(s) end in a tool drop."]
    path = out / "noise_tolerance.md"
    path.write_text("\n".join(lines) + "\n")
    return path


__all__ = ["measure", "tolerances", "tolerance_table", "write_report", "NoisyScriptedPolicy", "DIMENSIONS",
           "DEFAULT_LEVELS"]
