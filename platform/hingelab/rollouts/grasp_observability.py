"""Can a policy (or a critic) on ToolPick-v0's observation see where its tips hold the object?

A check that can fail, on any ToolPick-v0 dataset with ``/step`` and ``/sim/privileged`` (training rollouts,
``eval high``): at each episode's lift (``grasp_offsets.lift_step``), the true grasp offset (the tips'
midpoint minus the object's centre, hand_base frame, mm) is regressed, by least squares with an intercept,
on three inputs:

* the observation the policy acts on (the tool pose from perception, the latent, the object with its
  noise, the target, the extent);
* the same with the tool pose replaced by the true one (the simulator's tool position and quaternion);
* the same with the true object centre as well.

Only lifts with the object's centre between the tips (along the closing direction) count: a lift of empty
tips has no grasp offset to see.

The held-out R^2 per axis (a seeded two-thirds / one-third split of the episodes) says how much of the
offset each input explains linearly. If the observation explains an axis poorly and the true tool pose
recovers it, the policy cannot centre its grasp along that axis better than its tool-pose estimate allows,
whatever it learns; if the observation already explains it, the information is there and a learner could
use it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError
from hingelab.rollouts.grasp_offsets import AXES, grasp_at, read_episodes
from hingelab.rollouts.reward_diagnostic import write_tables
from hingelab.tasks import OBSERVED_OBJECT, OBSERVED_TOOL_POSE

INPUTS = ("observation", "true tool pose", "true tool pose and object")
MIN_EPISODES = 30
CLOSING = 1  # the hand's y axis: the tips close along it (grasp_offsets)


def samples(roots) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The three inputs (episodes x features) and the true offsets (episodes x 3, mm) at each lift."""
    rows = {name: [] for name in INPUTS}
    offsets = []
    for root in roots:
        for _, episode, t in read_episodes(root, "diagnose grasp-observability"):
            if t is None:
                continue
            step, privileged = episode.topics["/step"], episode.topics["/sim/privileged"]
            a, b, obj = grasp_at(privileged, t)
            offset = (a + b) / 2 - obj
            if abs(offset[CLOSING]) > abs(a - b)[CLOSING] / 2:  # the object is not between the tips: no grasp
                continue
            observation = np.asarray(step["observation"][t], float)
            tool = np.r_[privileged["tool_position"][t], privileged["tool_orientation"][t]]
            rest = np.delete(observation, np.r_[np.arange(OBSERVED_TOOL_POSE.start, OBSERVED_TOOL_POSE.stop),
                                                  np.arange(OBSERVED_OBJECT.start, OBSERVED_OBJECT.stop)])
            rows["observation"].append(observation)
            rows["true tool pose"].append(np.r_[tool, observation[OBSERVED_TOOL_POSE.stop:]])
            rows["true tool pose and object"].append(np.r_[tool, obj, rest])
            offsets.append(1000 * offset)
    return {name: np.asarray(v) for name, v in rows.items()}, np.asarray(offsets)


def held_out_r2(features: np.ndarray, target: np.ndarray, seed: int) -> float:
    """R^2 on a held-out third of the episodes of a least-squares fit (with intercept) on the other two."""
    order = np.random.default_rng(seed).permutation(len(target))
    fit, test = order[: 2 * len(order) // 3], order[2 * len(order) // 3:]
    design = np.c_[features, np.ones(len(features))]
    weights, *_ = np.linalg.lstsq(design[fit], target[fit], rcond=None)
    residual = target[test] - design[test] @ weights
    return float(1 - residual.var() / target[test].var())


def measure(roots, seed: int = 0) -> list[dict]:
    """One row per input: the held-out R^2 of each axis's offset, with the offsets' spread."""
    inputs, offsets = samples(roots)
    if len(offsets) < MIN_EPISODES:
        raise ConfigError(f"{len(offsets)} episodes lifted the object between the tips; diagnose grasp-observability "
                          f"needs at least {MIN_EPISODES} (give more episodes, e.g. a training run's RUNDIR/dataset)")
    out = []
    for name in INPUTS:
        row = {"input": name, "episodes": len(offsets)}
        for k, axis in enumerate(AXES):
            row[f"offset_{axis}_sd_mm"] = float(offsets[:, k].std())
            row[f"r2_{axis}"] = held_out_r2(inputs[name], offsets[:, k], seed)
        out.append(row)
    return out


def verdict(rows: list[dict], axis: str) -> str:
    seen, true_tool = (next(r[f"r2_{axis}"] for r in rows if r["input"] == name) for name in INPUTS[:2])
    if seen >= 0.7:
        return f"along {axis}, the observation explains the grasp offset (R^2 {seen:.2f}): the information is there"
    if true_tool >= 0.5 and true_tool - seen >= 0.3:
        return (f"along {axis}, the observation explains little of the grasp offset (R^2 {seen:.2f}) and the true tool "
                f"pose most of it ({true_tool:.2f}): the tool-pose estimate is what the policy cannot see past")
    return (f"along {axis}, the observation explains little of the grasp offset (R^2 {seen:.2f}) and the true tool "
            f"pose does not recover it ({true_tool:.2f})")


def write_report(rows: list[dict], out, command: str) -> Path:
    """``observability.csv`` and ``observability.md`` under ``out``; the markdown's path."""
    out = write_tables(out, {"observability.csv": rows})
    lines = ["# Can the policy see where its tips hold the object?", "",
             f"Made by `{command}` (`hingelab.rollouts.grasp_observability`). At each episode's first lift command, "
             "the true grasp offset (the tips' midpoint minus the object's centre, hand_base frame, mm: y the closing "
             "direction, x the lift, z across both) regressed by least squares on each input; R^2 on a held-out third "
             f"of the {rows[0]['episodes']} episodes whose lift held the object's centre between the tips.", "",
             "| input | " + " | ".join(f"R^2 {a}" for a in AXES) + " |", "|---|" + "---|" * len(AXES)]
    for r in rows:
        lines.append(f"| {r['input']} | " + " | ".join(f"{r[f'r2_{a}']:.2f}" for a in AXES) + " |")
    lines += ["", "Spread of the true offsets (sd, mm): " +
              ", ".join(f"{a} {rows[0][f'offset_{a}_sd_mm']:.2f}" for a in AXES) + ".", "", "Verdicts:", ""]
    lines += [f"- {verdict(rows, a)}." for a in AXES] + [""]
    path = Path(out) / "observability.md"
    path.write_text("\n".join(lines))
    return path
