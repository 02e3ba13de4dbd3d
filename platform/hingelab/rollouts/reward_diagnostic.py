"""Does the high-level reward pay finishing more than lingering? ``hingelab diagnose reward``.

The scripted demonstrator picks each object twice from the same start (the same reset seed): once as
it does (it succeeds), once told a target 1.1 cm below the real one, so that it carries the object
there and holds it just outside the 1 cm success radius until the time limit (it hovers). For each
episode and each reward mode (``hingelab.envs.rewards``: "paper", eq. 8-10 alone, and "absorbing")
it computes what a critic with discount gamma learns the episode is worth at its decision point, the
first step with the object within 2 cm of the target: the discounted rewards from there on, plus, for
an episode cut off by the time limit, the bootstrap a critic adds there, the last step's reward held
forever (``r_T / (1 - gamma)``: the hover goes on). A reward that pays finishing must value the
success above the hover on every seed; the paper's reward does not (module doc of
``hingelab.envs.rewards``).

The env runs with mode "absorbing"; each step's terms (``info["reward_terms"]``) give both modes'
rewards (the paper's is the sum without the absorbing term).
"""

from __future__ import annotations

import csv
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from hingelab.envs import TOOL_PICK_ID
from hingelab.envs.rewards import HIGH_LEVEL_REWARD_MODES, HighLevelRewardConfig
from hingelab.errors import ConfigError
from hingelab.policies.baselines import ScriptedPolicy
from hingelab.seeds import eval_high_seed

HOVER_OFFSET_M = 0.011  # below the target: 1 mm outside the success radius
DECISION_DISTANCE_M = 0.02  # the decision point: the object first this close to the target


class HoveringScriptedPolicy(ScriptedPolicy):
    """The scripted demonstrator carrying to a target ``HOVER_OFFSET_M`` below the real one and holding there."""

    def reset(self, env, seed: int) -> None:
        super().reset(env, seed)
        self.heuristic.target = self.heuristic.target - np.array([0.0, 0.0, HOVER_OFFSET_M])


def step_rewards(terms: list[dict], mode: str, gamma: float) -> np.ndarray:
    """Each step's reward in ``mode`` from the terms the env recorded (any mode's: the absorbing term is
    recomputed from the sparse term, which is nonzero exactly on the success step)."""
    config = HighLevelRewardConfig(mode=mode, gamma=gamma)
    rewards = []
    for t in terms:
        base = t["sparse"] + t["tool_object"] + t["object_target"] + t["penalty"]
        rewards.append(base + (config.absorbing_bonus if t["sparse"] > 0 else 0.0))
    return np.asarray(rewards, float)


def discounted_values(rewards, truncated: bool, gamma: float) -> np.ndarray:
    """Each step's discounted rewards from there on, plus at a time-limit cut the last step's reward held
    forever (what a critic's fixed point gives a state that goes on as it ended)."""
    rewards = np.asarray(rewards, float)
    values = np.empty(len(rewards))
    following = rewards[-1] / (1.0 - gamma) if truncated else 0.0
    for t in range(len(rewards) - 1, -1, -1):
        following = rewards[t] + gamma * following
        values[t] = following
    return values


def critic_value(rewards: np.ndarray, start: int, truncated: bool, gamma: float) -> float:
    """``discounted_values`` of step ``start``."""
    return float(discounted_values(np.asarray(rewards, float)[start:], truncated, gamma)[0])


@dataclass
class EpisodeTrace:
    kind: str  # "success" (the demonstrator) or "hover"
    seed: int
    success: bool
    truncated: bool
    terms: list
    object_target_m: np.ndarray

    @property
    def decision_step(self) -> int | None:
        near = np.flatnonzero(self.object_target_m < DECISION_DISTANCE_M)
        return int(near[0]) if len(near) else None


def run_trace(env, policy, kind: str, seed: int) -> EpisodeTrace:
    env.reset(seed=seed)
    policy.reset(env, seed)
    obs, terms, distances = None, [], []
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(env, obs))
        terms.append(dict(info["reward_terms"]))
        distances.append(info["object_target_distance"])
        if terminated or truncated:
            return EpisodeTrace(kind, seed, bool(info["is_success"]), bool(truncated and not terminated), terms,
                                np.asarray(distances, float))


def diagnose(episodes: int = 10, seed: int = 9100, gamma: float = 0.98, object: str = "sphere", size: float = 0.02,
             progress: bool = True) -> list[dict]:
    """Rows of the diagnostic table: one per (episode, kind, mode); see the module doc."""
    if episodes < 1:
        raise ConfigError(f"--episodes must be at least 1, not {episodes}")
    env = gym.make(TOOL_PICK_ID, object=object, size=size, reward=asdict(HighLevelRewardConfig(gamma=gamma)))
    rows = []
    try:
        bar = tqdm(total=2 * episodes, desc="diagnose reward", disable=not progress, unit="episode")
        for i in range(episodes):
            episode_seed = eval_high_seed(seed, i)
            for kind, policy in (("success", ScriptedPolicy()), ("hover", HoveringScriptedPolicy())):
                trace = run_trace(env, policy, kind, episode_seed)
                bar.update(1)
                for mode in HIGH_LEVEL_REWARD_MODES:
                    rewards = step_rewards(trace.terms, mode, gamma)
                    decision = trace.decision_step
                    rows.append({
                        "episode": i, "seed": episode_seed, "kind": kind, "mode": mode, "success": trace.success,
                        "length": len(rewards), "truncated": trace.truncated, "return": float(rewards.sum()),
                        "value_at_start": critic_value(rewards, 0, trace.truncated, gamma),
                        "decision_step": decision,
                        "value_at_decision": (None if decision is None
                                              else critic_value(rewards, decision, trace.truncated, gamma)),
                    })
        bar.close()
    finally:
        env.close()
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    """Per mode: mean values of the successes and the hovers, and on how many paired seeds the success
    is worth more at the decision point (episodes where either missed its role are left out)."""
    out = []
    for mode in HIGH_LEVEL_REWARD_MODES:
        pairs = {}
        for r in rows:
            if r["mode"] == mode:
                pairs.setdefault(r["episode"], {})[r["kind"]] = r
        usable = [p for p in pairs.values()
                  if p["success"]["success"] and not p["hover"]["success"] and p["hover"]["truncated"]
                  and p["success"]["value_at_decision"] is not None and p["hover"]["value_at_decision"] is not None]
        success_v = [p["success"]["value_at_decision"] for p in usable]
        hover_v = [p["hover"]["value_at_decision"] for p in usable]
        out.append({
            "mode": mode, "pairs": len(usable), "left_out": len(pairs) - len(usable),
            "success_value_at_decision": float(np.mean(success_v)) if usable else float("nan"),
            "hover_value_at_decision": float(np.mean(hover_v)) if usable else float("nan"),
            "success_return": float(np.mean([p["success"]["return"] for p in usable])) if usable else float("nan"),
            "hover_return": float(np.mean([p["hover"]["return"] for p in usable])) if usable else float("nan"),
            "finishing_pays_more": sum(s > h for s, h in zip(success_v, hover_v)),
        })
    return out


def write_tables(out, tables: dict[str, list[dict]]) -> Path:
    """Each list of rows as the CSV file of its name under ``out`` (created); ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, table in tables.items():
        with open(out / name, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(table[0]))
            writer.writeheader()
            writer.writerows(table)
    return out


def write_report(rows: list[dict], summary: list[dict], out: Path, command: str, gamma: float) -> Path:
    """``episodes.csv``, ``summary.csv`` and ``reward_diagnostic.md`` under ``out``; the markdown's path."""
    out = write_tables(out, {"episodes.csv": rows, "summary.csv": summary})
    lines = [
        "# The high-level reward: is finishing worth more than lingering?", "",
        f"Made by `{command}`. The scripted demonstrator from the same starts, once succeeding and once "
        f"holding the object {100 * HOVER_OFFSET_M:.1f} cm below the target until the time limit; the value "
        f"a critic with gamma {gamma:g} learns at the decision point (the object first within "
        f"{100 * DECISION_DISTANCE_M:g} cm of the target), a time-limit cut bootstrapped with its last reward "
        "held forever (`hingelab.rollouts.reward_diagnostic`).", "",
        "| reward mode | pairs | value of succeeding | value of hovering | succeeding worth more | "
        "episode return, success | episode return, hover |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        lines.append(f"| {s['mode']} | {s['pairs']} | {s['success_value_at_decision']:.1f} | "
                     f"{s['hover_value_at_decision']:.1f} | {s['finishing_pays_more']} of {s['pairs']} | "
                     f"{s['success_return']:.1f} | {s['hover_return']:.1f} |")
    left_out = max(s["left_out"] for s in summary)
    if left_out:
        lines += ["", f"{left_out} pair(s) left out: the demonstrator failed, or the hover succeeded or ended "
                      "before the time limit (`episodes.csv`)."]
    path = out / "reward_diagnostic.md"
    path.write_text("\n".join(lines) + "\n")
    return path


__all__ = ["diagnose", "summarize", "write_report", "write_tables", "step_rewards", "critic_value", "discounted_values",
           "HoveringScriptedPolicy"]
